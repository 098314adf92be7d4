"""GPS antenna position and velocity (paper eqs. 4-5), vectorised over sigma points."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.models._quat import cross, qrot
from svains.models.state import P, Q, V, W

F64 = NDArray[np.float64]


def gps_position(X: F64, p_B_G: F64) -> F64:
    """Antenna position ``p_W_G = p_W_B + R_W_B p_B_G``: (S, nx) -> (S, 3) m."""
    r = np.asarray(p_B_G, dtype=float)
    return X[:, P] + qrot(X[:, Q].T, r[:, None]).T


def gps_velocity(X: F64, p_B_G: F64) -> F64:
    """Antenna velocity ``v_W_G = v_W_B + R_W_B (ω_B × p_B_G)``: (S, nx) -> (S, 3) m/s."""
    r = np.asarray(p_B_G, dtype=float)[:, None]
    return X[:, V] + qrot(X[:, Q].T, cross(X[:, W].T, r)).T


def gps_position_velocity(X: F64, p_B_G: F64) -> F64:
    """Stacked ``(p_W_G, v_W_G)``: (S, nx) -> (S, 6)."""
    return np.concatenate([gps_position(X, p_B_G), gps_velocity(X, p_B_G)], axis=1)


def correlated_position_scale(correlation_s: float, spacing_s: float | None) -> float:
    """The factor on a fix's position variance that leaves fixes ``spacing_s`` (s) apart,
    whose noise stays correlated over ``correlation_s`` τ (s), the information of
    independent ones: ``max(1, 2τ/Δt)`` (a first-order Gauss-Markov noise averaged over a
    span T holds that of T/2τ independent samples). 1 for white noise or a first fix."""
    if correlation_s <= 0.0 or spacing_s is None or spacing_s <= 0.0:
        return 1.0
    return max(1.0, 2.0 * correlation_s / spacing_s)
