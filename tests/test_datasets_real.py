"""Readers on the real data in ../shared/data (EuRoC V1_01 micro, KITTI odometry excerpt)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset, stereo_pairs
from svains.geometry.rotation import quat_to_rotmat

pytestmark = pytest.mark.realdata


def test_euroc_micro_counts_and_calibration(
    euroc_micro: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(euroc_micro)
    # cam1/data.csv lists 99 frames, 4 at the end have no file: one warning with the count.
    warnings = [r for r in caplog.records if "absent on disk" in r.getMessage()]
    assert len(warnings) == 1 and "4 image(s)" in warnings[0].getMessage()
    assert ds.missing_images == {"cam1": 4}
    assert len(ds.left) == 95 and len(ds.right) == 95
    assert ds.imu.t_ns.size == 29120
    span_s = (ds.imu.t_ns[-1] - ds.imu.t_ns[0]) * 1e-9
    assert span_s == pytest.approx(145.6, abs=0.05)
    assert ds.imu_calib.rate_hz == 200.0
    assert 1e9 / np.median(np.diff(ds.imu.t_ns)) == pytest.approx(200.0, rel=1e-3)
    assert ds.groundtruth.t_ns.size == 2895
    assert 1e9 / np.median(np.diff(ds.groundtruth.t_ns)) == pytest.approx(20.0, rel=1e-3)
    assert ds.groundtruth.t_ns[0] == ds.left.t_ns[0] == 1403715273262142976
    np.testing.assert_allclose(np.linalg.norm(ds.groundtruth.q_W_B_wxyz, axis=1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(ds.cam0.intrinsics, [458.654, 457.296, 367.215, 248.375])
    assert ds.cam0.resolution == (752, 480)
    assert ds.cam0.distortion[3] == 1.76187114e-05
    assert ds.imu_calib.gyro_noise_density == 1.6968e-04
    # EuRoC's stereo baseline is about 11 cm.
    T_C0_C1 = np.linalg.inv(ds.cam0.T_B_C) @ ds.cam1.T_B_C
    assert np.linalg.norm(T_C0_C1[:3, 3]) == pytest.approx(0.110, abs=0.002)
    np.testing.assert_array_equal(ds.gravity_W, [0.0, 0.0, -9.81])
    # At rest the accelerometer reads about +g in norm.
    assert np.linalg.norm(ds.imu.accel_B[:200].mean(axis=0)) == pytest.approx(9.81, abs=0.15)
    t, il, ir = stereo_pairs(ds)
    assert t.size == 95
    np.testing.assert_array_equal(ds.left.t_ns[il], ds.right.t_ns[ir])
    img = ds.left.load(0)
    assert img.shape == (480, 752) and img.dtype == np.uint8


def test_kitti_reader(kitti_a: Path) -> None:
    ds = load_dataset(kitti_a)
    assert len(ds.left) == 51 and len(ds.right) == 51
    assert ds.imu is None
    b = ds.cam1.T_B_C[0, 3]
    assert b == pytest.approx(3.798145e02 / 7.070912e02)
    np.testing.assert_array_equal(ds.cam0.intrinsics, [707.0912, 707.0912, 601.8873, 183.1104])
    np.testing.assert_array_equal(ds.cam0.distortion, np.zeros(4))
    assert ds.cam0.resolution == (1226, 370)
    assert ds.left.load(3).shape == (370, 1226)
    gt = ds.groundtruth
    assert gt.t_ns.size == 51 and gt.t_ns[1] == 100_000_000
    raw = np.loadtxt(kitti_a / "poses.txt").reshape(-1, 3, 4)
    np.testing.assert_array_equal(gt.p_W_B, raw[:, :, 3])
    np.testing.assert_allclose(quat_to_rotmat(gt.q_W_B_wxyz), raw[:, :, :3], atol=1e-6)
    # about 1.2 m per 0.1 s frame, forward along z
    assert np.median(gt.v_W_B[:, 2]) == pytest.approx(12.0, abs=1.0)
    np.testing.assert_array_equal(gt.bg_B, 0.0)
    t, il, ir = stereo_pairs(ds)
    assert t.size == 51 and il.tolist() == ir.tolist() == list(range(51))
