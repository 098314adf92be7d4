"""The camera-IMU rotation and time offset a run estimated online
(``vision.estimate_extrinsics``, ``vision.estimate_time_offset``), as a calibration file another
run can take (``--calib``).

The estimate is ``δφ_C`` (rad, axes of the rectified left camera the filter works in): the
rectified rig's ``R_B_C`` becomes ``R_B_C Exp(δφ_C)`` (``navigation.vision_clones``). On the
raw cameras that is ``R_B_C0 Exp(R_C0_Cr δφ_C)`` (``R_C0_Cr`` the rectifying rotation, so that
rectifying the turned pair gives the turned rig). ``camchain_estimated.yaml`` is the data
set's camera calibration with that rotation applied to both cameras, in Kalibr's
camchain-imucam layout (``datasets.kalibr.write_camchain``; intrinsics, distortion and the lever
arm unchanged). Its ``timeshift_cam_imu`` is the estimated offset (``vision.time_offset_ms``,
the calibration's own plus the filter's residual), or the data set's when not estimated; the
estimates' standard deviations are written as comments at the top.
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
from svains.navigation.vision_sources import rig_from_calibrations

CAMCHAIN_NAME = "camchain_estimated.yaml"


def turn_cameras(ds: Dataset, phi_C0_rad: ArrayLike) -> Dataset:
    """``ds`` with the stereo rig turned rigidly about the left camera's centre: cam0's
    ``R_B_C`` becomes ``R_B_C0 Exp(phi_C0)`` (``phi_C0`` (3,) rad in raw cam0 axes) and cam1
    keeps its pose relative to cam0 (as the filter's rectified rig turns as a whole)."""
    if ds.cam0 is None or ds.cam1 is None:
        return ds
    T_B_C0 = np.asarray(ds.cam0.T_B_C, dtype=float)
    turn_B = np.eye(4)  # rotation of the rig about cam0's centre, body axes
    turn_B[:3, :3] = T_B_C0[:3, :3] @ so3_exp(np.asarray(phi_C0_rad, float)) @ T_B_C0[:3, :3].T
    turn_B[:3, 3] = T_B_C0[:3, 3] - turn_B[:3, :3] @ T_B_C0[:3, 3]
    return replace(ds, cam0=replace(ds.cam0, T_B_C=turn_B @ T_B_C0),
                   cam1=replace(ds.cam1, T_B_C=turn_B @ np.asarray(ds.cam1.T_B_C, float)))


def corrected_calibration(ds: Dataset, phi_Cr_rad: ArrayLike) -> Dataset:
    """``ds`` with the rotation correction ``phi_Cr`` (3,) rad, in the rectified left camera's
    axes as the filter estimates it, applied to both raw cameras."""
    if ds.cam0 is None or ds.cam1 is None:
        return ds
    R_B_Cr = np.asarray(rig_from_calibrations(ds.cam0, ds.cam1).R_B_C, dtype=float)
    R_C0_Cr = np.asarray(ds.cam0.T_B_C, dtype=float)[:3, :3].T @ R_B_Cr
    return turn_cameras(ds, R_C0_Cr @ np.asarray(phi_Cr_rad, dtype=float))


def write_estimated_camchain(out_dir: Path, ds: Dataset, report: dict[str, Any]) -> Path | None:
    """Write ``out_dir/camchain_estimated.yaml`` when ``report`` holds an online rotation
    (``vision.extrinsic_rotation_deg``) or time-offset (``vision.time_offset_ms``) estimate;
    None (nothing written) otherwise."""
    vision = report.get("vision", {})
    phi_deg = vision.get("extrinsic_rotation_deg")
    offset_ms = vision.get("time_offset_ms")
    if (phi_deg is None and offset_ms is None) or ds.cam0 is None or ds.cam1 is None:
        return None
    turned = ds if phi_deg is None else corrected_calibration(ds, np.radians(phi_deg))
    T_B_I = ds.imu_calib.T_B_S if ds.imu_calib is not None else None
    shift = ds.cam0.timeshift_cam_imu_s if offset_ms is None else float(offset_ms) * 1e-3
    comments = ["svains online calibration estimate (report.json vision.*)"]
    if phi_deg is not None:
        std = vision.get("extrinsic_rotation_std_deg")
        comments.append(f"rotation correction [deg, rectified cam0 axes]: {_fmt(phi_deg)}, "
                        f"std {_fmt(std)}")  # fmt: skip
    if offset_ms is not None:
        comments.append(f"timeshift_cam_imu [s]: {shift:.6f}, std "
                        f"{float(vision.get('time_offset_std_ms', float('nan'))) * 1e-3:.6f}")
    return write_camchain(Path(out_dir) / CAMCHAIN_NAME, (turned.cam0, turned.cam1), T_B_I, shift,
                          comments=comments)  # fmt: skip


def _fmt(values: Any) -> str:
    """A list of numbers as ``[a, b, c]`` with 4 decimals (``?`` when missing)."""
    if values is None:
        return "?"
    return "[" + ", ".join(f"{float(v):.4f}" for v in values) + "]"
