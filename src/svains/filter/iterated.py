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
import scipy.linalg.lapack
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
    R_low_rank: F64 | None = None,
) -> tuple[F64, F64, float, tuple[F64, F64]]:
    """Posterior mean (nx,), covariance (ndx, ndx), the last iteration's NIS and (gain ``K^T``
    (nz, ndx), ``S^-1 r`` (nz,)) of fusing
    ``z`` (nz,) with model ``h`` (S, nx) -> (S, nz) and noise ``R`` (nz, nz), or its diagonal
    (nz,), plus ``D^T D`` for ``R_low_rank`` = D (k, nz), into the prior ``x0`` (nx,), ``P0``
    (ndx, ndx), linearised ``iterations`` (>= 1) times.

    A diagonal ``R`` with many measurements (nz > 2 S) and non-negative covariance weights is
    solved in information form in O(nz (S + ndx)²) instead of O(nz³) (``_low_rank_update``):
    the linearisation error ``Ω`` and ``D^T D`` have rank S and k at most, and the posterior
    ``L0 (I + L0^T H^T E^-1 H L0)^-1 L0^T`` (``E = R + Ω + D^T D``) is positive definite by
    construction, whatever the strength of the frame against the prior.
    """
    nz = z.size
    D = None if R_low_rank is None else np.asarray(R_low_rank, dtype=float)
    Wm, Wc = points.Wm, points.Wc
    fast = np.ndim(R) == 1 and nz > 2 * Wc.size and bool(np.all(Wc >= 0.0))
    if not fast:
        R = np.diag(R) if np.ndim(R) == 1 else R
        if D is not None:
            R = R + D.T @ D
    L0 = safe_cholesky(P0, f"iterated prior covariance of {name}") if fast else None
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
        if fast:
            assert L0 is not None
            F = _linearisation_error_factor(dY, Wc)
            if D is not None:
                F = np.vstack([F, D])
            P_next, KT, dx, Sr = _low_rank_update(R, F, H @ L0, L0, r, name)
            nis = float(r @ Sr)
        else:
            PHt = P0 @ H.T
            Omega = dY.T @ WdY - H @ Pj @ H.T
            S = H @ PHt + R + Omega
            L = safe_cholesky(0.5 * (S + S.T), f"iterated innovation covariance of {name}")
            KT = scipy.linalg.cho_solve((L, True), PHt.T, check_finite=False)
            w = scipy.linalg.solve_triangular(L, r, lower=True, check_finite=False)
            nis = float(w @ w)
            Sr = scipy.linalg.solve_triangular(L, w, lower=True, trans="T", check_finite=False)
            P_next = P0 - PHt @ KT
            P_next = 0.5 * (P_next + P_next.T)
            dx = KT.T @ r
        xj = manifold.retract(x0[None, :], dx[None, :])[0]
        Pj = P_next
    return xj, Pj, nis, (KT, Sr)


def _linearisation_error_factor(dY: F64, Wc: F64) -> F64:
    """``F`` (n + 1, nz) with ``F^T F = Ω = dY^T W dY - H Pj H^T``, the statistical
    linearisation's error, for the Merwe points' offsets ``0, ±c L`` (``Pj = L L^T``) and
    weights ``Wc`` (2n + 1,), all >= 0. The regression ``H`` explains the antisymmetric part
    of each ± pair exactly, so what it leaves is the centre's deviation and each pair's
    symmetric part (the model's curvature): ``Ω = Wc0 dY0 dY0^T + Σ_i (Wc_i / 2) s_i s_i^T``,
    ``s_i = dY_+i + dY_-i``."""
    n = (Wc.size - 1) // 2
    pairs = dY[1 : n + 1] + dY[n + 1 :]
    return np.vstack([np.sqrt(Wc[0]) * dY[:1], np.sqrt(0.5 * Wc[1 : n + 1])[:, None] * pairs])


def _low_rank_update(
    Rd: F64, F: F64, HL0: F64, L0: F64, r: F64, name: str
) -> tuple[F64, F64, F64, F64]:
    """Posterior covariance (ndx, ndx), gain ``K^T`` (nz, ndx), correction ``K r`` (ndx,) and
    ``S^-1 r`` (nz,) for the prior ``P0 = L0 L0^T``, ``H L0`` (nz, n) and the innovation
    covariance ``S = E + (H L0)(H L0)^T``, ``E = diag(Rd) + F^T F`` (F (m, nz), m small).

    Information form: ``P+ = L0 M^-1 L0^T`` with ``M = I + (H L0)^T E^-1 H L0``,
    ``K = P+ H^T E^-1``; ``E^-1`` and ``S^-1`` by the matrix inversion lemma. Both capacitance
    matrices (``I + F E0^-1 F^T`` and ``M``) are symmetric and at least the identity, so the
    Cholesky factors exist and no subtraction can make the posterior indefinite."""
    Fd = F / Rd  # (m, nz)
    Lf = safe_cholesky(np.eye(F.shape[0]) + Fd @ F.T, f"iterated noise capacitance of {name}")
    B = np.column_stack([HL0, r])
    EB = B / Rd[:, None] - Fd.T @ scipy.linalg.cho_solve((Lf, True), Fd @ B, check_finite=False)
    Ea, Er = EB[:, :-1], EB[:, -1]
    M = np.eye(HL0.shape[1]) + HL0.T @ Ea
    Lm = safe_cholesky(0.5 * (M + M.T), f"iterated information capacitance of {name}")
    Mi = scipy.linalg.cho_solve((Lm, True), np.column_stack([L0.T, HL0.T @ Er]),
                                check_finite=False)  # fmt: skip
    MiL0T, Mig = Mi[:, :-1], Mi[:, -1]
    P = L0 @ MiL0T
    return 0.5 * (P + P.T), Ea @ MiL0T, L0 @ Mig, Er - Ea @ Mig


def _solve_psd(P: F64, B: F64, name: str) -> F64:
    """``P^-1 B`` for a covariance ``P`` (n, n) and ``B`` (n, k)."""
    # Factorised and its condition estimated as scipy.linalg.solve does, without its
    # LinAlgWarning: ill-conditioned past round-off (an exact clone direction, rcond 1.6e-17 on
    # a probe's simulated MH_03 at 0.2 Hz) is repaired as a failed factorisation is, not
    # solved inexactly under a warning on the user's console (nor through the process-wide
    # warning filters, which are no thread's own: a review).
    c, info = scipy.linalg.lapack.dpotrf(P, lower=True, clean=True)
    if info == 0:
        rcond, info = scipy.linalg.lapack.dpocon(c, float(np.max(np.sum(np.abs(P), axis=0))),
                                                 uplo="L")  # fmt: skip
        if info == 0 and rcond >= np.finfo(float).eps:
            return scipy.linalg.cho_solve((c, True), B, check_finite=False)
    L = safe_cholesky(P, f"iterated covariance of {name}")  # PSD to round-off: repaired
    return scipy.linalg.cho_solve((L, True), B, check_finite=False)

