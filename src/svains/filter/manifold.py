"""Manifold description used by the UKF: state dimension ``nx``, tangent dimension ``ndx``.

``retract(X (S, nx), dX (S, ndx)) -> (S, nx)`` is the box-plus, ``local(X (S, nx), x_ref (nx,))
-> (S, ndx)`` its inverse (box-minus, ``retract(x_ref, local(X, x_ref)) == X``), ``mean(X, w)``
the weighted mean on the manifold (weights may be negative and sum to one).

A manifold may also declare *consider* parameters, ``consider -> (slice, slice) | None``: the
columns in ``x`` and in the tangent of Euclidean numbers (equal in both) that the filter carries
with their covariance but never updates (the Schmidt-Kalman filter: an uncertain calibration
whose effect on the other states' covariance is kept, while its value stays the prior's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


class Manifold(Protocol):
    """What the UKF needs to know about the state space."""

    @property
    def nx(self) -> int: ...

    @property
    def ndx(self) -> int: ...

    def retract(self, X: F64, dX: F64) -> F64: ...

    def local(self, X: F64, x_ref: F64) -> F64: ...

    def mean(self, X: F64, w: F64) -> F64: ...


@dataclass(frozen=True)
class Euclidean:
    """Plain vector space R^n (the UKF then is the textbook one); ``consider_cols`` (start,
    stop): the consider parameters among them (None: none)."""

    n: int
    consider_cols: tuple[int, int] | None = None

    @property
    def consider(self) -> tuple[slice, slice] | None:
        if self.consider_cols is None:
            return None
        c = slice(*self.consider_cols)
        return c, c

    @property
    def nx(self) -> int:
        return self.n

    @property
    def ndx(self) -> int:
        return self.n

    def retract(self, X: F64, dX: F64) -> F64:
        return X + dX

    def local(self, X: F64, x_ref: F64) -> F64:
        return X - x_ref

    def mean(self, X: F64, w: F64) -> F64:
        return w @ X
