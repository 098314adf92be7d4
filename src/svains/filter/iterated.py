"""Iterated posterior linearisation (IPLF) of one sigma-point measurement update.

A single sigma-point update linearises ``h`` statistically over the *prior*. When the prior is
wide against the measurement (after an IMU gap the attitude may be uncertain by several degrees
while stereo pixels pin the motion to a fraction of one), that linearisation is poor: the update
stops short of what the measurement says, or its innovation looks too large and is gated out.
IPLF (García-Fernández, Svensson, Morelande, Särkkä, "Posterior linearization filter:
principles and implementation using sigma points", IEEE TSP 2015) linearises again over the
current posterior approximation and re-applies the update to the prior, a few times:

- statistical linear regression of ``h`` over sigma points of ``(x_j, P_j)``:
  ``H = Ψ^T P_j^-1``, ``Ω = Φ - H P_j H^T`` (Ψ the state-measurement cross covariance, Φ the
  measurement covariance of the points, Ω the linearisation error, added to R);
- a Kalman update of the prior ``(x_0, P_0)`` with ``z ≈ ȳ_j + H (x ⊟ x_j) + e``,
  ``e ~ N(0, R + Ω)``, which gives ``(x_{j+1}, P_{j+1})``.

The first iteration is the plain sigma-point update. Tangent offsets of the prior mean are taken
in the tangent space at ``x_j`` and the correction is retracted at ``x_0`` (first order in the
difference, a few degrees at most). Pure numpy/scipy; the filter's conventions (``ukf``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from svains.filter.manifold import Manifold
from svains.filter.sigma_points import MerweScaledSigmaPoints, safe_cholesky

F64 = NDArray[np.float64]


def iterated_update(
    manifold: Manifold,
    points: MerweScaledSigmaPoints,
    x0: F64,
    P0: F64,
    h: Callable[[F64], F64],
    z: F64,
    R: F64,
    iterations: int,
    name: str = "",
) -> tuple[F64, F64, float]:
    """Posterior mean (nx,), covariance (ndx, ndx) and the last iteration's NIS of fusing
    ``z`` (nz,) with model ``h`` (S, nx) -> (S, nz) and noise ``R`` (nz, nz) into the prior
    ``x0`` (nx,), ``P0`` (ndx, ndx), linearised ``iterations`` (>= 1) times."""
    nz = z.size
    Wm, Wc = points.Wm, points.Wc
    xj, Pj = x0, P0
    nis = float("nan")
    for _ in range(iterations):
        dX = points.offsets(Pj)
        X = manifold.retract(np.broadcast_to(xj, (dX.shape[0], xj.size)), dX)
        Y = np.asarray(h(X), dtype=float).reshape(X.shape[0], nz)
        y = Wm @ Y
        dY = Y - y
        WdY = Wc[:, None] * dY
        Psi = dX.T @ WdY  # (ndx, nz)
        try:
            H = scipy.linalg.solve(Pj, Psi, assume_a="pos", check_finite=False).T  # (nz, ndx)
        except np.linalg.LinAlgError:  # P_j PSD to round-off only (an exact clone): repaired
            Lj = safe_cholesky(Pj, f"iterated covariance of {name}")
            H = scipy.linalg.cho_solve((Lj, True), Psi, check_finite=False).T
        Omega = dY.T @ WdY - H @ Pj @ H.T
        e0 = manifold.local(x0[None, :], xj)[0]  # the prior mean in x_j's tangent space
        r = z - y - H @ e0
        PHt = P0 @ H.T
        S = H @ PHt + R + Omega
        L = safe_cholesky(0.5 * (S + S.T), f"iterated innovation covariance of {name}")
        KT = scipy.linalg.cho_solve((L, True), PHt.T, check_finite=False)
        w = scipy.linalg.solve_triangular(L, r, lower=True, check_finite=False)
        nis = float(w @ w)
        xj = manifold.retract(x0[None, :], (KT.T @ r)[None, :])[0]
        Pj = P0 - PHt @ KT
        Pj = 0.5 * (Pj + Pj.T)
    return xj, Pj, nis
