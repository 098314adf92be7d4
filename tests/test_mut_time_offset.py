"""The camera-IMU time offset is applied once (issue 26: applying a Kalibr camchain's
``timeshift_cam_imu`` on top of the data set's own, already applied at read time, survived the
suite: the real data set it was tested on has no offset of its own).

A small stereo data set written to disk whose cameras' sensor.yaml carry an offset: the reader
moves the image stamps to the IMU clock by it, and a camchain with another offset replaces it
(the stamps end on the camera clock plus the camchain's offset, not plus both). The same for
``features0``, whose frames are the cameras' frames on their clock (before 2026-12-03 neither the
reader nor a camchain moved them: a feature-level run given its true offset ran on the camera
clock).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from svains.datasets import load_dataset
from svains.datasets.asl_writer import AslWriter
from svains.datasets.kalibr import apply_kalibr, write_camchain
from svains.datasets.types import FeatureStream
from test_vision_updater import _calibs

T_CAM_NS = np.array([1_000_000_000, 1_050_000_000, 1_100_000_000], np.int64)  # camera clock
OWN_S = 0.004  # the data set's sensor.yaml: t_imu = t_cam + 4 ms
CHAIN_S = -0.0025  # the Kalibr camchain's


def _stereo_folder(root: Path) -> Path:
    w = AslWriter(root)
    for cal in _calibs():
        shape = (cal.resolution[1], cal.resolution[0])
        folder = w.write_camera(cal, T_CAM_NS, (np.zeros(shape, np.uint8) for _ in T_CAM_NS))
        with (folder / "sensor.yaml").open("a") as f:
            f.write(f"timeshift_cam_imu: {OWN_S}\n")
    t = np.repeat(T_CAM_NS, 2)
    uv = np.tile([[10.0, 20.0], [30.0, 40.0]], (len(T_CAM_NS), 1))
    w.write_features(FeatureStream(t, np.tile([1, 2], len(T_CAM_NS)), uv, uv - [5.0, 0.0], 0.5))
    return root


def test_sensor_yaml_offset_moves_the_stamps_once(tmp_path: Path) -> None:
    ds = load_dataset(_stereo_folder(tmp_path / "ds"))
    assert ds.cam0 is not None and ds.cam0.timeshift_cam_imu_s == OWN_S
    np.testing.assert_array_equal(ds.left.t_ns, T_CAM_NS + 4_000_000)
    np.testing.assert_array_equal(ds.right.t_ns, T_CAM_NS + 4_000_000)
    np.testing.assert_array_equal(ds.features.frame_times(), T_CAM_NS + 4_000_000)


def test_camchain_offset_replaces_the_one_applied_at_read_time(tmp_path: Path) -> None:
    ds = load_dataset(_stereo_folder(tmp_path / "ds"))
    assert ds.cam0 is not None and ds.cam1 is not None
    chain = write_camchain(tmp_path / "camchain.yaml", [ds.cam0, ds.cam1],
                           timeshift_cam_imu_s=CHAIN_S)  # fmt: skip
    out = apply_kalibr(ds, chain, None)
    np.testing.assert_array_equal(out.left.t_ns, T_CAM_NS - 2_500_000)
    np.testing.assert_array_equal(out.right.t_ns, T_CAM_NS - 2_500_000)
    np.testing.assert_array_equal(out.features.frame_times(), T_CAM_NS - 2_500_000)
    assert out.cam0 is not None and out.cam0.timeshift_cam_imu_s == CHAIN_S
    assert out.extras["timeshift_cam_imu_ns"] == -6_500_000  # what was added to the stamps
    # The data set read again is unchanged (the copy carries the shift, not the files).
    np.testing.assert_array_equal(load_dataset(tmp_path / "ds").left.t_ns, T_CAM_NS + 4_000_000)

