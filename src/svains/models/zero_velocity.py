"""Zero-velocity pseudo-measurement: the body's velocity in the world frame, to be zero while the
platform rests (``navigation.zupt``)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.models.state import V

F64 = NDArray[np.float64]


def body_velocity(X: F64) -> F64:
    """``v_W_B`` (S, 3) m/s of the sigma points ``X`` (S, nx)."""
    return np.ascontiguousarray(X[:, V])
