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


def test_chord_residual_measures_what_a_missing_sample_leaves_unknown() -> None:
    """White noise: 1.5 σ²; a vibration A sin(2πft): A²/2 (1 − cos 2πfh)²; irregular triples
    (a hole) are not counted; too few triples leave it unmeasured."""
    from svains.models.imu import MIN_CHORD_TRIPLES, chord_residual_variance

    h = 0.005
    rng = np.random.default_rng(3)
    t = np.arange(20000) * h
    sigma = 0.03
    white = rng.normal(0.0, sigma, (t.size, 3))
    assert chord_residual_variance(t, white, h) == pytest.approx(1.5 * sigma**2, rel=0.03)
    A, f = 2.0, 37.0
    vib = A * np.sin(2 * np.pi * f * t[:, None] + np.array([0.0, 1.0, 2.0]))
    expect = A**2 / 2 * (1 - np.cos(2 * np.pi * f * h)) ** 2
    assert chord_residual_variance(t, vib, h) == pytest.approx(expect, rel=0.02)
    # The trapezoid across a hole at k misses exactly h e_k of the integral.
    k = 777
    full = h * (vib[k - 1] / 2 + vib[k] + vib[k + 1] / 2)
    across = h * (vib[k - 1] + vib[k + 1])
    e_k = vib[k] - (vib[k - 1] + vib[k + 1]) / 2
    np.testing.assert_allclose(full - across, h * e_k, atol=1e-12)
    # Triples that straddle a hole are left out: a hole next to a spike does not count it.
    spiky = white.copy()
    spiky[1000] = 50.0
    keep = np.ones(t.size, bool)
    keep[999] = keep[1001] = False
    assert chord_residual_variance(t[keep], spiky[keep], h) == pytest.approx(
        1.5 * sigma**2, rel=0.03
    )
    n = MIN_CHORD_TRIPLES + 1  # n samples, n - 2 triples
    assert np.isnan(chord_residual_variance(t[:n], white[:n], h))
    assert np.isfinite(chord_residual_variance(t[: n + 1], white[: n + 1], h))


def test_a_missing_sample_is_priced_by_the_chord_residual() -> None:
    from svains.models.imu import white_noise_duration_s

    h = 0.005
    one_hole = (np.array([2 * h]), np.array([2 * h]))
    # White noise alone (chord residual 1.5 σ²/h ⇒ 1.5 h of white noise): the held sample's
    # 4 h already covers it, as before.
    assert white_noise_duration_s(*one_hole, h, missing_sample_s=1.5 * h) == pytest.approx(4 * h)
    # A vibrating airframe: the missing sample is worth 300 h of white noise on top of the step.
    assert white_noise_duration_s(*one_hole, h, missing_sample_s=300 * h) == pytest.approx(302 * h)
    # Split by a frame time inside the hole, the pieces add up to the same.
    pieces = white_noise_duration_s(
        np.array([0.3 * h, 1.7 * h]), np.array([2 * h, 2 * h]), h, missing_sample_s=300 * h
    )
    assert pieces == pytest.approx(302 * h)
    # Three samples missing: three times the price.
    D = np.array([4 * h])
    three = white_noise_duration_s(D, D, h, missing_sample_s=300 * h)
    assert three == pytest.approx(4 * h + 900 * h)
    # A regular stream is untouched.
    dt = np.full(5, h)
    assert white_noise_duration_s(dt, dt, h, missing_sample_s=300 * h) == pytest.approx(5 * h)


def _vibrating_hole_filter(amplitude: float):
    """An InsFilter on the analytic flight at 200 Hz with a 37 Hz vibration of ``amplitude``
    m/s² on the accelerometer and one sample missing at 2 s."""
    from svains.datasets.types import ImuStream
    from svains.navigation.init import initialise
    from svains.navigation.ins import InsFilter
    from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions
    from svains.replay.replay import history_from_dataset

    ds = make_dataset(3.0, imu_hz=200.0)
    imu = ds.imu
    t_s = (imu.t_ns - imu.t_ns[0]) * 1e-9
    accel = imu.accel_B + amplitude * np.sin(2 * np.pi * 37.0 * t_s[:, None] + [0.0, 1.0, 2.0])
    hole = 400
    keep = np.arange(imu.t_ns.size) != hole
    ds = replace(ds, imu=ImuStream(imu.t_ns[keep], imu.gyro_B[keep], accel[keep]))
    init = initialise(ds, BIASED, InitOptions(mode="groundtruth"))
    init.P *= 1e-12  # the growth across the hole is then the process noise alone
    ins = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), BIASED, init,
                    FilterOptions(), NoiseOptions())
    return ins, int(imu.t_ns[hole - 1]), int(imu.t_ns[hole + 1]), accel


@pytest.mark.parametrize("amplitude", [0.0, 2.0])
def test_a_hole_in_a_vibrating_stream_costs_the_velocity_what_it_hides(amplitude) -> None:
    """Across one missing sample the velocity variance grows by at least h² var(e) per axis
    (the integral the trapezoid misses); a quiet stream keeps the white-noise price."""
    from svains.models.imu import chord_residual_variance

    ins, t_before, t_after, accel = _vibrating_hole_filter(amplitude)
    h = 0.005
    # The same span of two regular steps just before: what the hole adds is the difference.
    ins.propagate_to(t_before - int(2 * h * 1e9))
    var0 = np.diag(ins.ukf.P)[DV].copy()
    ins.propagate_to(t_before)
    var1 = np.diag(ins.ukf.P)[DV].copy()
    ins.propagate_to(t_after)
    extra = (np.diag(ins.ukf.P)[DV] - var1) - (var1 - var0)
    white = ins.noise.accel_noise_density**2 * 2 * h  # the held sample's 4 h against 2 h
    t_s = np.arange(accel.shape[0]) * h
    var_e = chord_residual_variance(t_s[144:400], accel[144:400], h)
    if amplitude == 0.0:
        np.testing.assert_allclose(extra, white, rtol=0.2)
    else:
        assert h * h * var_e > 100 * white
        np.testing.assert_allclose(extra, h * h * var_e, rtol=0.05)
