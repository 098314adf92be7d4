"""IMU process model: closed-form constant-rate and coning motion, lever arm, stencil, noise."""

from __future__ import annotations

import numpy as np
import pytest

from _fd import numeric_jacobian
from svains.filter import MerweScaledSigmaPoints
from svains.geometry.rotation import quat_box_minus, quat_exp, quat_multiply, quat_to_rotmat, skew
from svains.models.imu import ImuChunk, ImuNoise, angular_acceleration, process_noise, propagate
from svains.models.imu_preint import node_weights, propagate_preintegrated
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, PAPER, StateLayout

G_W = np.array([0.0, 0.0, -9.81])
LAYOUTS = [PAPER, BIASED]
PROPAGATORS = [propagate, propagate_preintegrated]


def _x0(layout: StateLayout, p, v, q, w) -> np.ndarray:
    x = np.zeros(layout.nx)
    x[0:3], x[3:6], x[6:10], x[10:13] = p, v, q, w
    return x


def _chunk(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> ImuChunk:
    return ImuChunk(np.diff(t), gyro, accel, angular_acceleration(t, gyro))


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("prop", PROPAGATORS)
def test_constant_rate_and_constant_acceleration_are_exact(layout, prop) -> None:
    w = np.array([0.3, -0.5, 0.8])
    a_W = np.array([0.5, -0.2, 0.3])
    q0 = quat_exp([0.2, 0.1, -0.4])
    t = np.linspace(0.0, 5.0, 501)
    q_t = quat_multiply(q0, quat_exp(t[:, None] * w))
    f = np.einsum("nji,j->ni", quat_to_rotmat(q_t), a_W - G_W)
    x = _x0(layout, [1, 2, 3], [0.5, 0.1, -0.2], q0, w)
    y = prop(x[None], _chunk(t, np.tile(w, (501, 1)), f), layout, G_W, np.zeros(3))[0]
    T = 5.0
    np.testing.assert_allclose(
        y[0:3], [1, 2, 3] + np.array([0.5, 0.1, -0.2]) * T + a_W * T**2 / 2, atol=1e-9
    )
    np.testing.assert_allclose(y[3:6], np.array([0.5, 0.1, -0.2]) + a_W * T, atol=1e-10)
    np.testing.assert_allclose(quat_box_minus(y[6:10], q_t[-1]), 0.0, atol=1e-12)
    np.testing.assert_allclose(y[10:13], w, atol=1e-12)


def _coning(t: np.ndarray, beta: float, Om: float):
    s, c = np.sin(beta / 2), np.cos(beta / 2)
    q = np.stack([np.full_like(t, c), s * np.cos(Om * t), s * np.sin(Om * t), 0 * t], axis=1)
    w = np.stack([-Om * np.sin(beta) * np.sin(Om * t), Om * np.sin(beta) * np.cos(Om * t),
                  np.full_like(t, -2 * Om * s**2)], axis=1)  # fmt: skip
    return q, w


@pytest.mark.parametrize("layout", LAYOUTS)
def test_coning_motion_matches_closed_form_with_second_order_error(layout) -> None:
    beta, Om, T = 0.3, 2 * np.pi, 10.0
    errs = []
    for hz in (100, 200, 400):
        t = np.linspace(0.0, T, int(T * hz) + 1)
        q, w = _coning(t, beta, Om)
        x = _x0(layout, np.zeros(3), np.zeros(3), q[0], w[0])
        f = np.einsum("nji,j->ni", quat_to_rotmat(q), -G_W)  # hovering: specific force = -g
        y = propagate(x[None], _chunk(t, w, f), layout, G_W, np.zeros(3))[0]
        errs.append(np.linalg.norm(quat_box_minus(y[6:10], q[-1])))
    # 200 Hz, 10 s of 0.3 rad coning at 1 Hz (1.8 rad/s): measured 4.5e-4 rad (biased model,
    # gyro read directly) and 9.0e-4 rad (paper model, rate from the stencil).
    assert errs[1] < (5e-4 if layout.biased else 1e-3)
    # Second order: halving the step divides the error by ~4.
    assert 3.5 < errs[0] / errs[1] < 4.5 and 3.5 < errs[1] / errs[2] < 4.5


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("prop", PROPAGATORS)
def test_lever_arm_terms_cancel_the_accelerometer_offset(layout, prop) -> None:
    # B stays at the origin while spinning up about z; the accelerometer at r feels the
    # tangential and centripetal acceleration of its own point, which the model removes.
    r = np.array([0.2, -0.1, 0.05])
    t = np.linspace(0.0, 3.0, 601)
    th = 0.5 * t + 0.3 * t**2
    w = np.stack([0 * t, 0 * t, 0.5 + 0.6 * t], axis=1)
    alpha = np.array([0.0, 0.0, 0.6])
    q = quat_exp(th[:, None] * [0.0, 0.0, 1.0])
    a_A_B = np.cross(alpha, r) + np.cross(w, np.cross(w, r))
    f = a_A_B - np.einsum("nji,j->ni", quat_to_rotmat(q), G_W)
    x = _x0(layout, np.zeros(3), np.zeros(3), q[0], w[0])
    y = prop(x[None], _chunk(t, w, f), layout, G_W, r)[0]
    np.testing.assert_allclose(y[0:3], 0.0, atol=1e-5)
    np.testing.assert_allclose(y[3:6], 0.0, atol=1e-5)
    y_no_arm = prop(x[None], _chunk(t, w, f), layout, G_W, np.zeros(3))[0]
    assert np.linalg.norm(y_no_arm[0:3]) > 0.5  # the test would fail without the terms


def test_three_point_stencil_is_exact_for_quadratics_on_uneven_steps() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.004, 0.006, 50))
    g = np.stack([1 + 2 * t - 3 * t**2, 0.5 * t**2, 0 * t + 0.1], axis=1)
    a = angular_acceleration(t, g)
    np.testing.assert_allclose(a[2:], np.stack([2 - 6 * t, t, 0 * t], axis=1)[2:], atol=1e-9)
    # Even spacing: exactly the paper's (3ω_k − 4ω_{k−1} + ω_{k−2}) / 2δt.
    te = np.arange(10) * 0.01
    ge = rng.normal(size=(10, 3))
    np.testing.assert_allclose(
        angular_acceleration(te, ge)[2:], (3 * ge[2:] - 4 * ge[1:-1] + ge[:-2]) / 0.02, atol=1e-10
    )


@pytest.mark.parametrize("layout", LAYOUTS)
def test_preintegrated_sigma_points_match_exact_propagation(layout) -> None:
    rng = np.random.default_rng(1)
    t = np.arange(21) * 0.005
    gyro = np.stack([0.5 * np.sin(3 * t), 0.3 * np.cos(2 * t), 0.2 + 0.1 * t], axis=1)
    acc = np.stack([np.sin(t), 0.5 + t, 9.81 + 0.2 * np.cos(5 * t)], axis=1)
    chunk = _chunk(t, gyro, acc)
    m = NavManifold(layout)
    x = _x0(layout, [1, 2, 3], [0.5, -0.2, 0.1], quat_exp(rng.normal(size=3)), [0.1, 0.2, 0.3])
    if layout.biased:
        x[13:] = [0.01, -0.02, 0.005, 0.1, -0.1, 0.05]
    sp = MerweScaledSigmaPoints(layout.ndx)
    errs = []
    for scale in (1.0, 0.5):
        sd = np.r_[np.full(3, 1.0), np.full(3, 0.3), np.full(3, 0.1),
                   np.full(layout.ndx - 9, 0.01 * scale)]  # fmt: skip
        X = m.retract(np.tile(x, (sp.num_points, 1)), sp.offsets(np.diag(sd**2)))
        r = np.array([0.05, -0.03, 0.02])
        A = propagate(X, chunk, layout, G_W, r)
        B = propagate_preintegrated(X, chunk, layout, G_W, r)
        np.testing.assert_allclose(A[0], B[0], atol=1e-12)  # the reference point is exact
        errs.append(np.abs(m.local(B, A[0]) - m.local(A, A[0])).max())
    assert errs[0] < 1e-5
    assert errs[0] / errs[1] > 3.0  # second order in the rate/bias spread


def test_node_weights_integrate_polynomials_exactly() -> None:
    h = np.array([0.01, 0.02, 0.015, 0.005])
    t = np.r_[0.0, np.cumsum(h)]
    wv, wp = node_weights(h)
    T = t[-1]
    for a in (np.ones_like(t), t):  # the scheme is exact for piecewise-linear acceleration
        exact_v = np.trapezoid(a, t) if a[0] == 1.0 else T**2 / 2
        exact_p = T**2 / 2 if a[0] == 1.0 else T**3 / 6
        assert wv @ a == pytest.approx(exact_v, rel=1e-12)
        assert wp @ a == pytest.approx(exact_p, rel=1e-12)


def test_process_noise_blocks() -> None:
    n = ImuNoise(1e-3, 1e-4, 2e-2, 3e-3)
    Qb = process_noise(BIASED, n, 0.1, 0.005)
    Qp = process_noise(PAPER, n, 0.1, 0.005)
    assert Qb.shape == (18, 18) and Qp.shape == (12, 12)
    assert Qb[0, 0] == pytest.approx(4e-4 * 0.1**3 / 3) and Qb[0, 3] == pytest.approx(4e-4 * 0.005)
    assert Qb[6, 6] == pytest.approx(1e-6 * 0.1) and Qb[9, 9] == pytest.approx(1e-6 / 0.005)
    assert Qb[12, 12] == pytest.approx(1e-8 * 0.1) and Qb[15, 15] == pytest.approx(9e-6 * 0.1)
    assert Qp[9, 9] == pytest.approx(1e-8 * 0.1)
    assert np.all(np.linalg.eigvalsh(Qb) >= -1e-20)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("prop", PROPAGATORS)
def test_process_model_finite_differences_match_error_state_jacobians(layout, prop) -> None:
    rng = np.random.default_rng(2)
    t = np.arange(31) * 0.005
    gyro = np.stack([0.4 * np.sin(2 * t), 0.3 + 0 * t, -0.2 * np.cos(3 * t)], axis=1)
    acc = np.stack([0.3 + t, -0.2 * t, 9.9 + 0.1 * np.sin(4 * t)], axis=1)
    chunk = _chunk(t, gyro, acc)
    m = NavManifold(layout)
    x = _x0(layout, [1, -2, 3], [0.4, 0.2, -0.1], quat_exp(rng.normal(size=3)), gyro[0])
    if layout.biased:
        x[10:13] = gyro[0]  # ω = gyro − bg with bg = 0
    r = np.zeros(3)
    y = prop(x[None], chunk, layout, G_W, r)[0]
    J = numeric_jacobian(lambda X: m.local(prop(X, chunk, layout, G_W, r), y), x, m.retract,
                         layout.ndx)  # fmt: skip
    T = t[-1]
    R0, RK = quat_to_rotmat(x[6:10]), quat_to_rotmat(y[6:10])
    dv_B = R0.T @ (y[3:6] - x[3:6] - G_W * T)
    dp_B = R0.T @ (y[0:3] - x[0:3] - x[3:6] * T - G_W * T**2 / 2)
    I3 = np.eye(3)
    tol = {"atol": 1e-6, "rtol": 1e-6}
    np.testing.assert_allclose(J[0:3, 0:3], I3, **tol)  # ∂p/∂p0
    np.testing.assert_allclose(J[0:3, 3:6], T * I3, **tol)  # ∂p/∂v0
    np.testing.assert_allclose(J[3:6, 3:6], I3, **tol)  # ∂v/∂v0
    np.testing.assert_allclose(J[3:6, 0:3], 0 * I3, **tol)
    np.testing.assert_allclose(J[6:9, 6:9], RK.T @ R0, **tol)  # attitude error transport
    np.testing.assert_allclose(J[3:6, 6:9], -R0 @ skew(dv_B), **tol)
    np.testing.assert_allclose(J[0:3, 6:9], -R0 @ skew(dp_B), **tol)
    if layout.biased:
        # Accelerometer bias: ∂v/∂ba = −R0 ∫ΔR dt (here ≈ −R0 T for small rotations).
        assert np.linalg.norm(J[3:6, 15:18] + R0 * T) < 0.05 * T


def test_missing_samples_scale_the_white_noise_by_the_held_interval() -> None:
    from svains.models.imu import white_noise_duration_s

    h = 0.01  # a 100 Hz sensor
    # A regular stream (jitter below the missing-sample factor): the white terms span the steps.
    dt = np.array([0.01, 0.0101, 0.0099])
    assert white_noise_duration_s(dt, dt, h) == pytest.approx(dt.sum(), rel=1e-15)
    # One kept sample held over 250 ms: its white noise enters as σ² D² / h, 25x σ² D.
    assert white_noise_duration_s(np.array([0.25]), np.array([0.25]), h) == pytest.approx(6.25)
    # Split by a frame time inside the interval, the pieces add up to the same.
    pieces = white_noise_duration_s(np.array([0.1, 0.15]), np.array([0.25, 0.25]), h)
    assert pieces == pytest.approx(6.25)
    # A dropout (longer than MAX_HELD_INTERVAL_S) is the fault guard's gap, not a held sample.
    assert white_noise_duration_s(np.array([2.0]), np.array([2.0]), h) == pytest.approx(2.0)
    noise = ImuNoise(1e-3, 1e-4, 2e-2, 1e-3)
    Q1 = process_noise(BIASED, noise, 0.25, h)
    Q25 = process_noise(BIASED, noise, 0.25, h, white_duration_s=6.25)
    white = np.r_[0:9]  # p, v, θ: white-noise terms scale by 25
    np.testing.assert_allclose(Q25[np.ix_(white, white)], 25 * Q1[np.ix_(white, white)])
    np.testing.assert_array_equal(Q25[9:, 9:], Q1[9:, 9:])  # ω sample noise and random walks
