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
    assert white_noise_duration_s(*one_hole, h, hole_s=np.array([1.5 * h])) == pytest.approx(
        4 * h)
    # A vibrating airframe: the missing sample is worth 300 h of white noise on top of the step.
    assert white_noise_duration_s(*one_hole, h, hole_s=np.array([300 * h])) == pytest.approx(
        302 * h)
    # Split by a frame time inside the hole, the pieces add up to the same.
    pieces = white_noise_duration_s(
        np.array([0.3 * h, 1.7 * h]), np.array([2 * h, 2 * h]), h,
        hole_s=np.array([300 * h, 300 * h]),
    )
    assert pieces == pytest.approx(302 * h)
    # Three samples missing: what they are worth together.
    D = np.array([4 * h])
    three = white_noise_duration_s(D, D, h, hole_s=np.array([2000 * h]))
    assert three == pytest.approx(4 * h + 2000 * h)
    # A regular stream is untouched.
    dt = np.full(5, h)
    assert white_noise_duration_s(dt, dt, h, hole_s=np.full(5, 300 * h)) == pytest.approx(5 * h)


@pytest.mark.parametrize("m", [1, 2, 5, 10])
def test_the_chord_residual_across_m_missing_samples(m: int) -> None:
    """The trapezoid across m missing samples misses h S, S = Σ x_j − (m/2)(x_0 + x_{m+1}):
    white noise gives σ² (m + m²/2); a coherent vibration its own sum; windows holding an
    irregular interval are left out."""
    from svains.models.imu import chord_residual_variance

    h = 0.005
    rng = np.random.default_rng(11)
    t = np.arange(40000) * h
    sigma = 0.03
    white = rng.normal(0.0, sigma, (t.size, 3))
    assert chord_residual_variance(t, white, h, missing=m) == pytest.approx(
        sigma**2 * (m + m * m / 2), rel=0.04)
    A, f = 2.0, 37.0
    vib = A * np.sin(2 * np.pi * f * t[:, None] + np.array([0.0, 1.0, 2.0]))
    # each window's integral error, brute force: every sample's trapezoid against the chord's
    n = 3000
    full = np.stack([h * (vib[i:i + m + 2].sum(0) - 0.5 * (vib[i] + vib[i + m + 1]))
                     for i in range(n)])  # fmt: skip
    across = np.stack([(m + 1) * h * 0.5 * (vib[i] + vib[i + m + 1]) for i in range(n)])
    brute = np.mean((full - across) ** 2) / h**2
    assert chord_residual_variance(t[: n + m + 1], vib[: n + m + 1], h, missing=m) == \
        pytest.approx(brute, rel=1e-9)
    # a window across a hole is left out: a spike between two holes does not count
    spiky = white.copy()
    spiky[1000] = 50.0
    keep = np.ones(t.size, bool)
    keep[999] = keep[1001] = False
    assert chord_residual_variance(t[keep][: 1000 + m + 5], spiky[keep][: 1000 + m + 5], h,
                                   missing=m) < 3 * sigma**2 * (m + m * m / 2)  # fmt: skip


def _vibrating_hole_filter(amplitude: float, missing: int = 1, drops: tuple[int, ...] = (),
                           broadband: bool = False):  # fmt: skip
    """An InsFilter on the analytic flight at 200 Hz with a 37 Hz vibration of ``amplitude``
    m/s² on the accelerometer (``broadband``: a random one, AR(1) at 0.9, of that std) and
    ``missing`` samples missing at 2 s; ``drops``: single samples missing before it."""
    from svains.datasets.types import ImuStream
    from svains.navigation.init import initialise
    from svains.navigation.ins import InsFilter
    from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions
    from svains.replay.replay import history_from_dataset

    ds = make_dataset(3.0, imu_hz=200.0)
    imu = ds.imu
    t_s = (imu.t_ns - imu.t_ns[0]) * 1e-9
    accel = imu.accel_B + amplitude * np.sin(2 * np.pi * 37.0 * t_s[:, None] + [0.0, 1.0, 2.0])
    if broadband:
        rng = np.random.default_rng(8)
        e = rng.normal(0.0, amplitude * np.sqrt(1 - 0.81), (t_s.size, 3))
        vib = np.zeros_like(e)
        for k in range(1, t_s.size):
            vib[k] = 0.9 * vib[k - 1] + e[k]
        accel = imu.accel_B + vib
    hole = 400
    keep = (np.arange(imu.t_ns.size) < hole) | (np.arange(imu.t_ns.size) >= hole + missing)
    for k in drops:
        keep[k] = False
    ds = replace(ds, imu=ImuStream(imu.t_ns[keep], imu.gyro_B[keep], accel[keep]))
    init = initialise(ds, BIASED, InitOptions(mode="groundtruth"))
    init.P *= 1e-12  # the growth across the hole is then the process noise alone
    ins = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), BIASED, init,
                    FilterOptions(), NoiseOptions())
    return ins, int(imu.t_ns[hole - 1]), int(imu.t_ns[hole + missing]), accel


def _hole_growth(ins, t_before: int, t_after: int, n_steps: int, h: float):  # type: ignore[no-untyped-def]
    """The velocity variance (3,) a hole of ``n_steps`` intervals adds: its growth less that
    of the same span of regular steps just before it."""
    ins.propagate_to(t_before - int(n_steps * h * 1e9))
    var0 = np.diag(ins.ukf.P)[DV].copy()
    ins.propagate_to(t_before)
    var1 = np.diag(ins.ukf.P)[DV].copy()
    ins.propagate_to(t_after)
    return (np.diag(ins.ukf.P)[DV] - var1) - (var1 - var0)


@pytest.mark.parametrize(("amplitude", "missing"), [(0.0, 1), (2.0, 1), (2.0, 2), (2.0, 6)])
def test_a_hole_in_a_vibrating_stream_costs_the_velocity_what_it_hides(
    amplitude: float, missing: int
) -> None:
    """Across m missing samples the velocity variance grows by h² var(S) per axis (the integral
    the trapezoid across them misses, ``chord_residual_variance(…, missing=m)``), not m times
    one sample's (a coherent vibration misses more or less than that); a quiet stream keeps
    the white-noise price."""
    from svains.models.imu import chord_residual_variance

    ins, t_before, t_after, accel = _vibrating_hole_filter(amplitude, missing)
    h = 0.005
    n_steps = missing + 1
    extra = _hole_growth(ins, t_before, t_after, n_steps, h)
    # the held sample's (m + 1)² h against (m + 1) h
    white = ins.noise.accel_noise_density**2 * n_steps * (n_steps - 1) * h
    t_s = np.arange(accel.shape[0]) * h
    var_s = chord_residual_variance(t_s[144:400], accel[144:400], h, missing=missing)
    if amplitude == 0.0:
        np.testing.assert_allclose(extra, white, rtol=0.2)
    else:
        assert h * h * var_s > 100 * white
        np.testing.assert_allclose(extra, h * h * var_s, rtol=0.05)
        one = chord_residual_variance(t_s[144:400], accel[144:400], h)
        if missing > 1:  # the 37 Hz vibration: 4-6x what pricing each sample alike gives
            assert var_s / (missing * one) > 2.0


def test_a_long_hole_after_earlier_drops_is_priced_from_the_runs_the_window_has() -> None:
    """A hole of 60 samples whose 256 samples before hold four single drops: no regular run
    of 62 samples, and it was priced as white noise alone (0.001x its cost, a user's
    probe); now from the longest hole those runs measure, times the squared ratio."""
    from svains.models.imu import chord_residual_variance

    h, missing = 0.005, 60
    ins, t_before, t_after, accel = _vibrating_hole_filter(
        2.0, missing, drops=(190, 240, 290, 340), broadband=True)
    extra = _hole_growth(ins, t_before, t_after, missing + 1, h)
    t_s = np.arange(accel.shape[0]) * h
    actual = h * h * chord_residual_variance(t_s[:400], accel[:400], h, missing=missing)
    assert 0.5 < extra.mean() / actual < 3.0, extra.mean() / actual
