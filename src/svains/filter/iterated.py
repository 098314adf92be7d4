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

import warnings
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
) -> tuple[F64, F64, float, tuple[F64, F64]]:
    """Posterior mean (nx,), covariance (ndx, ndx), the last iteration's NIS and (gain ``K^T``
    (nz, ndx), ``S^-1 r`` (nz,)) of fusing
    ``z`` (nz,) with model ``h`` (S, nx) -> (S, nz) and noise ``R`` (nz, nz), or its diagonal
    (nz,), into the prior ``x0`` (nx,), ``P0`` (ndx, ndx), linearised ``iterations`` (>= 1)
    times. A diagonal ``R`` with many measurements (nz > 12 (S + ndx)) is solved by the matrix
    inversion lemma in O(nz (S + ndx)²) instead of O(nz³): ``H P0 H^T`` and ``Ω`` have rank
    ndx and S at most. An iteration whose lemma posterior is not positive definite (a strong
    frame over a prior metres wide: the lemma's subtraction loses the small eigenvalues) is
    solved densely instead."""
    nz = z.size
    diagonal = np.ndim(R) == 1
    # Below 12x the low rank the dense solve costs about as little, and it reproduces to the
    # last digits across BLAS builds (the goldens, Python 3.11 and 3.13: the lemma's LU of an
    # indefinite capacitance moved them by 4e-9 m).
    fast = diagonal and nz > 12 * (points.Wc.size + P0.shape[0])
    L0 = safe_cholesky(P0, f"iterated prior covariance of {name}") if fast else None
    Wm, Wc = points.Wm, points.Wc
    xj, Pj = x0, P0
    nis = float("nan")
    KT, Sr = np.zeros((nz, P0.shape[0])), np.zeros(nz)
    for _ in range(iterations):
        dX = points.offsets(Pj)
        X = manifold.retract(np.broadcast_to(xj, (dX.shape[0], xj.size)), dX)
        Y = np.asarray(h(X), dtype=float).reshape(X.shape[0], nz)
        y = Wm @ Y
        dY = Y - y
        WdY = Wc[:, None] * dY
        Psi = dX.T @ WdY  # (ndx, nz)
        H = _solve_psd(Pj, Psi, name).T  # (nz, ndx)
        e0 = manifold.local(x0[None, :], xj)[0]  # the prior mean in x_j's tangent space
        r = z - y - H @ e0
        PHt = P0 @ H.T
        P_next = None
        if fast:
            assert L0 is not None
            PjdX = _solve_psd(Pj, (Wc[:, None] * dX).T, name)  # (ndx, S)
            KT, Sr = _lemma_solve(R, H @ L0, dX, dY, Wc, PjdX, np.column_stack([PHt.T, r]))
            P_next = _posterior(P0, PHt, KT)
            if _positive_definite(P_next):
                Sr = Sr[:, 0]
                nis = float(r @ Sr)
            else:  # the lemma lost definiteness (a strong frame over a wide prior): dense
                P_next = None
        if P_next is None:
            Rm = np.diag(R) if diagonal else R
            Omega = dY.T @ WdY - H @ Pj @ H.T
            S = H @ PHt + Rm + Omega
            L = safe_cholesky(0.5 * (S + S.T), f"iterated innovation covariance of {name}")
            KT = scipy.linalg.cho_solve((L, True), PHt.T, check_finite=False)
            w = scipy.linalg.solve_triangular(L, r, lower=True, check_finite=False)
            nis = float(w @ w)
            Sr = scipy.linalg.solve_triangular(L, w, lower=True, trans="T", check_finite=False)
            P_next = _posterior(P0, PHt, KT)
        xj = manifold.retract(x0[None, :], (KT.T @ r)[None, :])[0]
        Pj = P_next
    return xj, Pj, nis, (KT, Sr)


def _posterior(P0: F64, PHt: F64, KT: F64) -> F64:
    """``P0 - P0 H^T K^T``, symmetrised."""
    P = P0 - PHt @ KT
    return 0.5 * (P + P.T)


def _positive_definite(P: F64) -> bool:
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


def _solve_psd(P: F64, B: F64, name: str) -> F64:
    """``P^-1 B`` for a covariance ``P`` (n, n) and ``B`` (n, k)."""
    try:
        return scipy.linalg.solve(P, B, assume_a="pos", check_finite=False)
    except np.linalg.LinAlgError:  # P PSD to round-off only (an exact clone): repaired
        L = safe_cholesky(P, f"iterated covariance of {name}")
        return scipy.linalg.cho_solve((L, True), B, check_finite=False)


def _lemma_solve(
    Rd: F64, HL0: F64, dX: F64, dY: F64, Wc: F64, PjWdX: F64, B: F64
) -> tuple[F64, F64]:
    """``S^-1 B`` (nz, k) split as (its first k-1 columns, its last) for
    ``S = diag(Rd) + H P0 H^T + Ω``: ``H P0 H^T = (H L0)(H L0)^T`` and
    ``Ω = dY^T W dY - H Pj H^T = dY^T Wt dY`` with ``Wt = W - W dX Pj^-1 dX^T W`` (S, S), both
    of low rank: ``S = diag(Rd) + U^T Λ U`` with ``U = [(H L0)^T; dY]``, ``Λ = diag(I, Wt)``,
    and ``S^-1 = R^-1 - R^-1 U^T Λ (I + U R^-1 U^T Λ)^-1 U R^-1`` (no inverse of Λ, which is
    singular). ``PjWdX`` = ``Pj^-1 dX^T W`` (ndx, S)."""
    n = HL0.shape[1]
    Wt = np.diag(Wc) - (Wc[:, None] * dX) @ PjWdX
    U = np.vstack([HL0.T, dY])  # (n + S, nz)
    m = U.shape[0]
    Lam = np.zeros((m, m))
    Lam[:n, :n] = np.eye(n)
    Lam[n:, n:] = 0.5 * (Wt + Wt.T)
    RiB = B / Rd[:, None]
    RiUt = U.T / Rd[:, None]
    cap = np.eye(m) + (U @ RiUt) @ Lam
    with warnings.catch_warnings():
        # An ill-conditioned capacitance is caught by the caller's definiteness check.
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        X = scipy.linalg.solve(cap, U @ RiB, check_finite=False)
    out = RiB - RiUt @ (Lam @ X)
    return out[:, :-1], out[:, -1:]
