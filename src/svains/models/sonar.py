"""Sonar altimeter (paper eqs. 6-7): range along the sensor's +z axis to flat ground.

The ground is the plane of height ``ground_height`` (m) along the up direction ``u = −g_W/|g_W|``
(so it works for z-up and NED worlds). Sensor origin ``p_W_S = p_W_B + R_W_B p_B_S`` and beam
direction ``d_W = R_W_B R_B_S e_z``; the ray meets the plane at
``ρ = (ground_height − u·p_W_S) / (u·d_W)``. For NED with a down-looking sonar this is the paper's
``h = −r_S,3 / R_33``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.models._quat import qrot
from svains.models.state import P, Q

F64 = NDArray[np.float64]


def sonar_range(X: F64, T_B_S: F64, g_W: F64, ground_height: float) -> F64:
    """Range (S, 1) m; negative or huge when the beam does not point at the ground."""
    T_B_S = np.asarray(T_B_S, dtype=float)
    up_W = -np.asarray(g_W, dtype=float) / np.linalg.norm(g_W)
    qT = X[:, Q].T
    p_W_S = X[:, P] + qrot(qT, T_B_S[:3, 3:4]).T
    d_W = qrot(qT, T_B_S[:3, 2:3]).T
    return ((ground_height - p_W_S @ up_W) / (d_W @ up_W))[:, None]
