"""The estimated camera rotation written as a Kalibr camchain and read back with ``--calib``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from svains.datasets.kalibr import apply_kalibr
from svains.datasets.types import CameraCalib, Dataset
from svains.evaluation.extrinsics import CAMCHAIN_NAME, write_estimated_camchain
from svains.geometry.rotation import so3_exp


def _dataset() -> Dataset:
    T0 = np.eye(4)
    T0[:3, :3] = so3_exp(np.array([-1.2, 1.2, -1.2]))  # x right, y down, z forward-ish
    T0[:3, 3] = [1.08, -0.31, 0.73]
    T1 = T0.copy()
    T1[:3, 3] += T0[:3, :3] @ np.array([0.54, 0.0, 0.0])
    intr = np.array([980.0, 981.0, 690.0, 233.0])
    dist = np.array([-0.37, 0.2, 0.002, 0.001, -0.07])  # five coefficients, as KITTI's
    cams = [CameraCalib(n, T, 4.8, (1392, 512), intr, "radtan", dist)
            for n, T in (("cam0", T0), ("cam1", T1))]
    return Dataset(root=Path("memory"), name="calib", cam0=cams[0], cam1=cams[1])


def test_estimated_rotation_round_trips_through_calib(tmp_path: Path) -> None:
    ds = _dataset()
    phi_deg = np.array([0.36, 0.34, -0.55])
    report = {"vision": {"extrinsic_rotation_deg": phi_deg.tolist()}}
    path = write_estimated_camchain(tmp_path, ds, report)
    assert path == tmp_path / CAMCHAIN_NAME
    back = apply_kalibr(ds, path)
    delta = so3_exp(np.radians(phi_deg))
    for old, new in ((ds.cam0, back.cam0), (ds.cam1, back.cam1)):
        np.testing.assert_allclose(new.T_B_C[:3, :3], old.T_B_C[:3, :3] @ delta, atol=1e-12)
        np.testing.assert_allclose(new.T_B_C[:3, 3], old.T_B_C[:3, 3], atol=1e-12)
        np.testing.assert_allclose(new.distortion, old.distortion)
    assert back.extras["timeshift_cam_imu_ns"] == 0  # the image stamps stay where they were


def test_nothing_written_without_an_estimate(tmp_path: Path) -> None:
    assert write_estimated_camchain(tmp_path, _dataset(), {"vision": {"frames": 3}}) is None
    assert write_estimated_camchain(tmp_path, _dataset(), {}) is None
    assert not (tmp_path / CAMCHAIN_NAME).exists()
