"""Magnetometer (paper eqs. 8-9): ``m_S = R_S_B R_W_B^T m_W``, vectorised over sigma points."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.models._quat import qrot
from svains.models.state import Q

F64 = NDArray[np.float64]


def magnetic_field(X: F64, m_W: F64, R_B_S: F64) -> F64:
    """Field in sensor components (S, 3) Gauss; ``R_B_S`` (3, 3) sensor-to-body rotation."""
    qc = X[:, Q].T * np.array([1.0, -1.0, -1.0, -1.0])[:, None]  # R^T = R(q*)
    m_B = qrot(qc, np.asarray(m_W, dtype=float)[:, None]).T
    return m_B @ np.asarray(R_B_S, dtype=float)  # row-wise R_B_S^T m_B
