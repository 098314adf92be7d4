"""GPS, magnetometer and sonar models: closed-form values and finite-difference Jacobians."""

from __future__ import annotations

import numpy as np
import pytest

from _fd import assert_jacobian
from svains.geometry.rotation import quat_exp, quat_normalize, quat_to_rotmat, skew
from svains.models.gps import gps_position, gps_position_velocity, gps_velocity
from svains.models.magnetometer import magnetic_field
from svains.models.manifold import NavManifold
from svains.models.sonar import sonar_range
from svains.models.state import BIASED, DP, DTH, DV, DW

MAN = NavManifold(BIASED)


def _state(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.zeros(BIASED.nx)
    x[0:3] = rng.normal(size=3) * 5 + [0, 0, 10]
    x[3:6] = rng.normal(size=3)
    x[6:10] = quat_normalize(quat_exp(rng.normal(size=3) * 0.3))
    x[10:13] = rng.normal(size=3)
    x[13:] = rng.normal(size=6) * 0.01
    return x


@pytest.mark.parametrize("seed", [0, 1])
def test_gps_matches_analytic_jacobian_and_lever_arm(seed: int) -> None:
    x = _state(seed)
    r = np.array([0.3, -0.2, 0.5])
    R = quat_to_rotmat(x[6:10])
    w = x[10:13]
    np.testing.assert_allclose(gps_position(x[None], r)[0], x[0:3] + R @ r, atol=1e-12)
    np.testing.assert_allclose(gps_velocity(x[None], r)[0], x[3:6] + R @ np.cross(w, r))
    J = np.zeros((6, 18))
    J[0:3, DP] = np.eye(3)
    J[0:3, DTH] = -R @ skew(r)
    J[3:6, DV] = np.eye(3)
    J[3:6, DTH] = -R @ skew(np.cross(w, r))
    J[3:6, DW] = -R @ skew(r)
    assert_jacobian(lambda X: gps_position_velocity(X, r), x, J, MAN.retract, 18)


def test_gps_velocity_is_the_time_derivative_of_gps_position() -> None:
    # Rigid motion: p(t) = p0 + v t, R(t) = R0 Exp(ω t); the antenna velocity is dp_G/dt.
    x = _state(3)
    r = np.array([0.4, 0.1, -0.3])
    dt = 1e-6
    x1 = x.copy()
    x1[0:3] += x[3:6] * dt
    x1[6:10] = quat_normalize(
        MAN.retract(x[None], np.r_[0, 0, 0, 0, 0, 0, x[10:13] * dt, np.zeros(9)][None])[0, 6:10]
    )
    fd = (gps_position(x1[None], r) - gps_position(x[None], r))[0] / dt
    np.testing.assert_allclose(fd, gps_velocity(x[None], r)[0], rtol=1e-5, atol=1e-6)


def test_magnetometer_closed_form_and_jacobian() -> None:
    x = _state(4)
    m_W = np.array([0.2, 0.05, -0.4])
    R_B_S = quat_to_rotmat(quat_exp([0.1, -0.2, 0.3]))
    R = quat_to_rotmat(x[6:10])
    m_S = R_B_S.T @ R.T @ m_W
    np.testing.assert_allclose(magnetic_field(x[None], m_W, R_B_S)[0], m_S, atol=1e-14)
    J = np.zeros((3, 18))
    J[:, DTH] = R_B_S.T @ skew(R.T @ m_W)
    assert_jacobian(lambda X: magnetic_field(X, m_W, R_B_S), x, J, MAN.retract, 18)


@pytest.mark.parametrize("g_W", [np.array([0.0, 0.0, -9.81]), np.array([0.0, 0.0, 9.81])])
def test_sonar_closed_form_for_z_up_and_ned(g_W: np.ndarray) -> None:
    up = -g_W / 9.81
    x = np.zeros(BIASED.nx)
    x[0:3] = 3.0 * up  # 3 m above the ground plane (height 0.5)
    tilt = 0.2
    # Body level with the world, then tilted about x; the sensor looks down along -up.
    T_B_S = np.eye(4)
    if up[2] > 0:
        T_B_S[:3, :3] = np.diag([1.0, -1.0, -1.0])
    x[6:10] = quat_exp([tilt, 0.0, 0.0])
    T_B_S[:3, 3] = [0.0, 0.0, 0.0]
    rng_m = sonar_range(x[None], T_B_S, g_W, 0.5)[0, 0]
    assert rng_m == pytest.approx(2.5 / np.cos(tilt), rel=1e-12)  # paper: h = -r_S3 / R33


def test_sonar_jacobian_with_lever_arm() -> None:
    x = _state(5)
    g_W = np.array([0.0, 0.0, -9.81])
    T_B_S = np.eye(4)
    T_B_S[:3, :3] = quat_to_rotmat(quat_exp([np.pi - 0.1, 0.05, 0.0]))  # roughly down
    T_B_S[:3, 3] = [0.1, -0.05, -0.2]
    x[6:10] = quat_exp([0.05, -0.1, 0.7])
    R = quat_to_rotmat(x[6:10])
    up = np.array([0.0, 0.0, 1.0])
    d = R @ T_B_S[:3, 2]
    p_S = x[0:3] + R @ T_B_S[:3, 3]
    rho = (0.0 - up @ p_S) / (up @ d)
    assert rho > 0
    J = np.zeros((1, 18))
    J[0, DP] = -up / (up @ d)
    dpS = -R @ skew(T_B_S[:3, 3])
    dd = -R @ skew(T_B_S[:3, 2])
    J[0, DTH] = (-up @ dpS) / (up @ d) - rho * (up @ dd) / (up @ d)
    np.testing.assert_allclose(sonar_range(x[None], T_B_S, g_W, 0.0)[0, 0], rho, rtol=1e-12)
    assert_jacobian(lambda X: sonar_range(X, T_B_S, g_W, 0.0), x, J, MAN.retract, 18)
