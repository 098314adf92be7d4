"""The estimated camera rotation written as a Kalibr camchain and read back with ``--calib``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from svains.datasets.kalibr import apply_kalibr
from svains.datasets.types import CameraCalib, Dataset
from svains.evaluation.extrinsics import CAMCHAIN_NAME, write_estimated_camchain
from svains.geometry.rotation import so3_exp, so3_log
from svains.navigation.vision_sources import rig_from_calibrations


def _dataset() -> Dataset:
    T0 = np.eye(4)
    T0[:3, :3] = so3_exp(np.array([-1.2, 1.2, -1.2]))  # x right, y down, z forward-ish
    T0[:3, 3] = [1.08, -0.31, 0.73]
    T1 = T0.copy()
    # cam1 turned 2 deg from cam0, as KITTI's: the rectified frame is not cam0's.
    T1[:3, :3] = T0[:3, :3] @ so3_exp(np.radians([0.5, 1.5, -1.0]))
    T1[:3, 3] += T0[:3, :3] @ np.array([0.54, 0.005, -0.004])
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
    # The filter's correction is in the rectified frame: rectifying the written pair gives the
    # rectified rig turned by it, and the relative pose of the two cameras is unchanged.
    rig, rig_back = (rig_from_calibrations(d.cam0, d.cam1) for d in (ds, back))
    np.testing.assert_allclose(
        rig_back.R_B_C, rig.R_B_C @ so3_exp(np.radians(phi_deg)), atol=1e-9)
    assert np.degrees(np.linalg.norm(so3_log(rig_back.R_B_C.T @ back.cam0.T_B_C[:3, :3]))) > 0.5
    rel = [np.linalg.inv(d.cam0.T_B_C) @ d.cam1.T_B_C for d in (ds, back)]
    np.testing.assert_allclose(rel[1], rel[0], atol=1e-12)
    np.testing.assert_allclose(back.cam0.T_B_C[:3, 3], ds.cam0.T_B_C[:3, 3], atol=1e-12)
    for old, new in ((ds.cam0, back.cam0), (ds.cam1, back.cam1)):
        np.testing.assert_allclose(new.distortion, old.distortion)
    assert back.extras["timeshift_cam_imu_ns"] == 0  # the image stamps stay where they were


def test_nothing_written_without_an_estimate(tmp_path: Path) -> None:
    assert write_estimated_camchain(tmp_path, _dataset(), {"vision": {"frames": 3}}) is None
    assert write_estimated_camchain(tmp_path, _dataset(), {}) is None
    assert not (tmp_path / CAMCHAIN_NAME).exists()
