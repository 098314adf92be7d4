"""Irregular IMU streams (KITTI raw: 10-250 ms spacing): each step's own length in propagation
and process noise, the sensor's rate for one sample's white noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from _ins_truth import make_dataset
from svains.geometry.rotation import quat_box_minus, quat_exp, quat_multiply, quat_to_rotmat
from svains.models.imu import ImuChunk, ImuNoise, angular_acceleration, process_noise, propagate
from svains.models.imu_preint import propagate_preintegrated
from svains.models.state import BIASED, DBA, DBG, DP, DTH, DV, DW, PAPER
from svains.navigation.ins import imu_sample_period
from svains.replay.replay import rig_from_dataset

G_W = np.array([0.0, 0.0, -9.81])
NOISE = ImuNoise(2e-3, 1e-4, 3e-2, 1e-3)


def _irregular_times(seed: int = 0) -> np.ndarray:
    """5 s of samples 10-250 ms apart (median about 40 ms), like KITTI raw's OXTS records."""
    rng = np.random.default_rng(seed)
    steps = np.concatenate([rng.choice([0.01, 0.04, 0.05, 0.25], 200, p=[0.3, 0.4, 0.2, 0.1])])
    t = np.concatenate([[0.0], np.cumsum(steps)])
    return t[t <= 5.0]


@pytest.mark.parametrize("layout", [PAPER, BIASED])
def test_gap_noise_equals_dense_accumulation(layout) -> None:
    """Q over one 0.25 s gap equals 25 steps of 10 ms propagated through the double integrator
    (exact for p, v, attitude and the bias walks; ω's white sample variance does not add up)."""
    T, n = 0.25, 25
    h = T / n
    Q_gap = process_noise(layout, NOISE, T, 0.01)
    Qh = process_noise(layout, NOISE, h, 0.01)
    Phi = np.eye(layout.ndx)
    Phi[DP, DV] = h * np.eye(3)
    Q = np.zeros_like(Qh)
    for _ in range(n):
        Q = Phi @ Q @ Phi.T + Qh
    accumulating = [DP, DV, DTH] + ([DBG, DBA] if layout.biased else [DW])
    for a in accumulating:
        for b in accumulating:
            np.testing.assert_allclose(Q_gap[a, b], Q[a, b], rtol=1e-9, atol=1e-18)
    if layout.biased:
        np.testing.assert_allclose(Q_gap[DW, DW], Qh[DW, DW])


@pytest.mark.parametrize("prop", [propagate, propagate_preintegrated])
def test_irregular_steps_propagate_like_dense_ones(prop) -> None:
    """Constant body rate and world acceleration: the irregular stream ends where the exact
    motion does (the scheme is exact for this motion whatever the steps)."""
    t = _irregular_times()
    w = np.array([0.3, -0.5, 0.8])
    a_W = np.array([0.5, -0.2, 0.3])
    q0 = quat_exp([0.2, 0.1, -0.4])
    q_t = quat_multiply(q0, quat_exp(t[:, None] * w))
    f = np.einsum("nji,j->ni", quat_to_rotmat(q_t), a_W - G_W)
    gyro = np.tile(w, (t.size, 1))
    chunk = ImuChunk(np.diff(t), gyro, f, angular_acceleration(t, gyro))
    x = np.zeros(BIASED.nx)
    x[0:3], x[3:6], x[6:10] = [1, 2, 3], [0.5, 0.1, -0.2], q0
    y = prop(x[None], chunk, BIASED, G_W, np.zeros(3))[0]
    T = t[-1]
    v0 = np.array([0.5, 0.1, -0.2])
    np.testing.assert_allclose(y[0:3], [1, 2, 3] + v0 * T + a_W * T**2 / 2, atol=1e-8)
    np.testing.assert_allclose(y[3:6], v0 + a_W * T, atol=1e-9)
    np.testing.assert_allclose(quat_box_minus(y[6:10], q_t[-1]), 0.0, atol=1e-10)


def test_angular_acceleration_is_exact_on_irregular_samples() -> None:
    t = _irregular_times(1)
    gyro = np.stack([0.1 + 0.2 * t - 0.05 * t**2, np.sin(0 * t), 0.3 * t], axis=1)
    alpha = angular_acceleration(t, gyro)
    expect = np.stack([0.2 - 0.1 * t, 0 * t, np.full_like(t, 0.3)], axis=1)
    np.testing.assert_allclose(alpha[2:], expect[2:], atol=1e-9)


def test_white_noise_period_is_the_sensor_rate_not_the_median_gap() -> None:
    ds = make_dataset(2.0, imu_hz=100.0)
    keep = np.r_[0 : len(ds.imu.t_ns) : 4]  # every 4th record: 40 ms apart
    sparse = replace(ds, imu=replace(ds.imu, t_ns=ds.imu.t_ns[keep], gyro_B=ds.imu.gyro_B[keep],
                                     accel_B=ds.imu.accel_B[keep]))
    assert imu_sample_period(rig_from_dataset(sparse)) == pytest.approx(0.01)
    no_cal = replace(sparse, imu_calib=None)
    assert imu_sample_period(rig_from_dataset(no_cal)) == pytest.approx(0.04)
