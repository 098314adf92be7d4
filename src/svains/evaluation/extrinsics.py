"""The camera-IMU rotation a run estimated online (``vision.estimate_extrinsics``), as a
calibration file another run can take (``--calib``).

The estimate is ``δφ_C`` (rad, left-camera axes): both cameras' ``R_B_C`` become
``R_B_C Exp(δφ_C)`` (``navigation.vision_clones``). ``camchain_estimated.yaml`` is the data
set's camera calibration with that rotation applied, in Kalibr's camchain-imucam layout
(``datasets.kalibr.write_camchain``; intrinsics, distortion and the lever arm unchanged).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from svains.datasets.kalibr import write_camchain
from svains.datasets.types import Dataset
from svains.geometry.rotation import so3_exp

CAMCHAIN_NAME = "camchain_estimated.yaml"


def turn_cameras(ds: Dataset, phi_C_rad: ArrayLike) -> Dataset:
    """``ds`` with both cameras' ``R_B_C`` replaced by ``R_B_C Exp(phi_C)`` (3,) rad."""
    if ds.cam0 is None or ds.cam1 is None:
        return ds
    delta = so3_exp(np.asarray(phi_C_rad, dtype=float))

    def turn(cam):  # type: ignore[no-untyped-def]
        T = np.array(cam.T_B_C, dtype=float)
        T[:3, :3] = T[:3, :3] @ delta
        return replace(cam, T_B_C=T)

    return replace(ds, cam0=turn(ds.cam0), cam1=turn(ds.cam1))


def write_estimated_camchain(out_dir: Path, ds: Dataset, report: dict[str, Any]) -> Path | None:
    """Write ``out_dir/camchain_estimated.yaml`` when ``report`` holds an online rotation
    estimate (``vision.extrinsic_rotation_deg``); None (nothing written) otherwise."""
    phi_deg = report.get("vision", {}).get("extrinsic_rotation_deg")
    if phi_deg is None or ds.cam0 is None or ds.cam1 is None:
        return None
    turned = turn_cameras(ds, np.radians(phi_deg))
    T_B_I = ds.imu_calib.T_B_S if ds.imu_calib is not None else None
    shift = ds.cam0.timeshift_cam_imu_s
    return write_camchain(Path(out_dir) / CAMCHAIN_NAME, (turned.cam0, turned.cam1), T_B_I, shift)
