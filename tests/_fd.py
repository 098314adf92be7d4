"""Generic finite-difference checker for models on the navigation manifold (test helper)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def numeric_jacobian(
    h: Callable[[F64], F64],
    x: F64,
    retract: Callable[[F64, F64], F64],
    ndx: int,
    eps: float = 1e-6,
) -> F64:
    """Central-difference Jacobian (nz, ndx) of ``h(x ⊞ δ)`` at δ = 0.

    ``h`` maps (S, nx) -> (S, nz) (a vectorised model); all 2·ndx perturbed states are evaluated
    in one call, which also exercises the model's vectorisation.
    """
    E = np.concatenate([np.eye(ndx), -np.eye(ndx)]) * eps
    X = retract(np.tile(x, (2 * ndx, 1)), E)
    Y = np.asarray(h(X)).reshape(2 * ndx, -1)
    return ((Y[:ndx] - Y[ndx:]) / (2 * eps)).T


def assert_jacobian(
    h: Callable[[F64], F64],
    x: F64,
    J_expected: F64,
    retract: Callable[[F64, F64], F64],
    ndx: int,
    rtol: float = 1e-6,
    atol: float = 1e-8,
) -> None:
    """Fail unless the finite-difference Jacobian of ``h`` matches ``J_expected``."""
    J = numeric_jacobian(h, x, retract, ndx)
    np.testing.assert_allclose(J, J_expected, rtol=rtol, atol=atol)
