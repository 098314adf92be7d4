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
