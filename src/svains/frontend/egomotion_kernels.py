"""Compiled inner loops of the RANSAC egomotion (numba): batched Gauss-Newton and scoring.

The arithmetic is that of ``svains.frontend.egomotion`` (eqs. 11-12): motion ``p_k = R p_{k-1} +
t``, residual = predicted minus measured pixels ``(u_l, v_l, u_r, v_r)`` at k, rotation updated
on the left ``R <- Exp(δθ) R``. These loops run per hypothesis and feature with a handful of
floating-point operations each; written with numpy they are dominated by the fixed cost of ~40
array calls per Gauss-Newton step (about 0.15 ms whatever the size), which made RANSAC the
largest stage of the front end. Compiled once per machine (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

F64 = NDArray[np.float64]

MIN_DEPTH_M = 1e-3
_DAMPING = 1e-9


@njit(cache=True, nogil=True)
def _accumulate(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, W: F64, dvar: F64, use_dvar: bool, f: float,
    cu: float, cv: float, b: float, A: F64, g: F64,
) -> float:
    """Normal matrix ``A`` (6, 6) and gradient ``g`` (6,) (both overwritten) of one problem:
    points ``P`` (M, 3), pixels ``L``/``Rr`` (M, 2), weights ``W`` (M,), depth variance over
    pixel variance ``dvar`` (M,) (used if ``use_dvar``). Returns the weighted squared error."""
    A[:, :] = 0.0
    g[:] = 0.0
    J = np.zeros((4, 6))
    r = np.zeros(4)
    ja = np.zeros(6)
    cost = 0.0
    for m in range(P.shape[0]):
        w = W[m]
        if w == 0.0:
            continue
        px = R[0, 0] * P[m, 0] + R[0, 1] * P[m, 1] + R[0, 2] * P[m, 2]
        py = R[1, 0] * P[m, 0] + R[1, 1] * P[m, 1] + R[1, 2] * P[m, 2]
        pz = R[2, 0] * P[m, 0] + R[2, 1] * P[m, 1] + R[2, 2] * P[m, 2]
        x, y, z = px + t[0], py + t[1], pz + t[2]
        if not z > MIN_DEPTH_M:  # also false for NaN
            continue
        iz = 1.0 / z
        fz = f * iz
        r[0] = x * fz + cu - L[m, 0]
        r[1] = y * fz + cv - L[m, 1]
        r[2] = (x - b) * fz + cu - Rr[m, 0]
        r[3] = y * fz + cv - Rr[m, 1]
        if not (np.isfinite(r[0]) and np.isfinite(r[1]) and np.isfinite(r[2])
                and np.isfinite(r[3])):  # fmt: skip
            continue
        c0 = -x * fz * iz
        c1 = -y * fz * iz
        c2 = c0 + b * fz * iz
        pzf = pz * fz
        # Rows: projection Jacobian times dq/d(δθ, δt) = [-[R p]x, I].
        J[0, 0] = py * c0
        J[0, 1] = pzf - px * c0
        J[0, 2] = -py * fz
        J[0, 3] = fz
        J[0, 4] = 0.0
        J[0, 5] = c0
        J[1, 0] = py * c1 - pzf
        J[1, 1] = -px * c1
        J[1, 2] = px * fz
        J[1, 3] = 0.0
        J[1, 4] = fz
        J[1, 5] = c1
        J[2, 0] = py * c2
        J[2, 1] = pzf - px * c2
        J[2, 2] = -py * fz
        J[2, 3] = fz
        J[2, 4] = 0.0
        J[2, 5] = c2
        for j in range(6):
            J[3, j] = J[1, j]
        # The right v row equals the left one (rectified rows): three distinct rows, the
        # second counted twice.
        r13 = r[1] + r[3]
        for i in range(6):
            g[i] += w * (J[0, i] * r[0] + J[1, i] * r13 + J[2, i] * r[2])
            for j in range(i, 6):
                A[i, j] += w * (J[0, i] * J[0, j] + 2.0 * J[1, i] * J[1, j] + J[2, i] * J[2, j])
        e2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]
        if use_dvar and P[m, 2] > 0.0 and np.isfinite(dvar[m]):
            # Depth uncertainty along the ray: residual covariance I + s2 a aᵀ, inverted by
            # Sherman-Morrison (a = residual change per metre of depth at k-1).
            iz0 = 1.0 / P[m, 2]
            ra0, ra1, ra2 = px * iz0, py * iz0, pz * iz0
            a0 = fz * ra0 + c0 * ra2
            a1 = fz * ra1 + c1 * ra2
            a2 = fz * ra0 + c2 * ra2
            s2 = dvar[m]
            c = s2 / (1.0 + s2 * (a0 * a0 + 2.0 * a1 * a1 + a2 * a2))
            ar = a0 * r[0] + a1 * (r[1] + r[3]) + a2 * r[2]
            wc = w * c
            for i in range(6):
                ja[i] = a0 * J[0, i] + a1 * (J[1, i] + J[3, i]) + a2 * J[2, i]
            for i in range(6):
                g[i] -= wc * ar * ja[i]
                for j in range(i, 6):
                    A[i, j] -= wc * ja[i] * ja[j]
            e2 -= c * ar * ar
        cost += w * e2
    for i in range(6):
        for j in range(i):
            A[i, j] = A[j, i]
    return cost


@njit(cache=True, nogil=True)
def _solve6(A: F64, g: F64, delta: F64) -> bool:
    """``delta = -(A + εI)^-1 g`` by Cholesky; False (and delta 0) if A is not positive definite."""
    Lc = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            s = A[i, j] + (_DAMPING if i == j else 0.0)
            for k in range(j):
                s -= Lc[i, k] * Lc[j, k]
            if i == j:
                if not s > 0.0:
                    delta[:] = 0.0
                    return False
                Lc[i, i] = math.sqrt(s)
            else:
                Lc[i, j] = s / Lc[j, j]
    y = np.zeros(6)
    for i in range(6):
        s = -g[i]
        for k in range(i):
            s -= Lc[i, k] * y[k]
        y[i] = s / Lc[i, i]
    for i in range(5, -1, -1):
        s = y[i]
        for k in range(i + 1, 6):
            s -= Lc[k, i] * delta[k]
        delta[i] = s / Lc[i, i]
    return True


@njit(cache=True, nogil=True)
def _rotate_left(R: F64, w0: float, w1: float, w2: float) -> None:
    """``R <- Exp(w) R`` in place (Rodrigues; series below 1e-4 rad)."""
    th2 = w0 * w0 + w1 * w1 + w2 * w2
    if th2 < 1e-8:
        a = 1.0 - th2 / 6.0
        bb = 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        bb = (1.0 - math.cos(th)) / th2
    # Exp(w) = I + a K + bb K², K = [w]x, K² = w wᵀ - |w|² I (no BLAS call from compiled code).
    E = np.empty((3, 3))
    w = (w0, w1, w2)
    for i in range(3):
        for j in range(3):
            E[i, j] = bb * w[i] * w[j] + (1.0 - bb * th2 if i == j else 0.0)
    E[0, 1] -= a * w2
    E[0, 2] += a * w1
    E[1, 0] += a * w2
    E[1, 2] -= a * w0
    E[2, 0] -= a * w1
    E[2, 1] += a * w0
    R0 = R.copy()
    for i in range(3):
        for j in range(3):
            R[i, j] = E[i, 0] * R0[0, j] + E[i, 1] * R0[1, j] + E[i, 2] * R0[2, j]


@njit(cache=True, nogil=True)
def _gauss_newton_one(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, W: F64, dvar: F64, use_dvar: bool, f: float,
    cu: float, cv: float, b: float, iterations: int, tol: float, A: F64, g: F64, delta: F64,
) -> None:
    """Refine one motion ``R`` (3, 3), ``t`` (3,) in place (``gauss_newton_batch``; ``A``, ``g``,
    ``delta`` are scratch)."""
    for _ in range(iterations):
        _accumulate(R, t, P, L, Rr, W, dvar, use_dvar, f, cu, cv, b, A, g)
        if not _solve6(A, g, delta):
            break
        _rotate_left(R, delta[0], delta[1], delta[2])
        t[0] += delta[3]
        t[1] += delta[4]
        t[2] += delta[5]
        big = 0.0
        for i in range(6):
            big = max(big, abs(delta[i]))
        if big < tol:
            break


@njit(cache=True, nogil=True)
def gauss_newton_batch(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, W: F64, dvar: F64, use_dvar: bool, f: float,
    cu: float, cv: float, b: float, iterations: int, tol: float,
) -> None:
    """Refine H motions ``R`` (H, 3, 3), ``t`` (H, 3) in place, problem h on points ``P[h]``
    (M, 3), pixels ``L[h]``/``Rr[h]`` (M, 2), weights ``W[h]`` (M,), depth variances
    ``dvar[h]`` (M,). Each stops once its update is below ``tol`` (rad, m)."""
    A = np.zeros((6, 6))
    g = np.zeros(6)
    delta = np.zeros(6)
    for h in range(R.shape[0]):
        _gauss_newton_one(R[h], t[h], P[h], L[h], Rr[h], W[h], dvar[h], use_dvar, f, cu, cv, b,
                          iterations, tol, A, g, delta)  # fmt: skip


@njit(cache=True, nogil=True)
def _sq_error(R: F64, t: F64, P: F64, L: F64, Rr: F64, m: int, f: float, cu: float, cv: float,
              b: float) -> float:  # fmt: skip
    """Squared larger-of-left-and-right pixel error (px²) of point ``P[m]`` moved by ``R``,
    ``t``; inf behind the camera (``MIN_DEPTH_M``) or for a NaN depth."""
    x = R[0, 0] * P[m, 0] + R[0, 1] * P[m, 1] + R[0, 2] * P[m, 2] + t[0]
    y = R[1, 0] * P[m, 0] + R[1, 1] * P[m, 1] + R[1, 2] * P[m, 2] + t[1]
    z = R[2, 0] * P[m, 0] + R[2, 1] * P[m, 1] + R[2, 2] * P[m, 2] + t[2]
    if not z > MIN_DEPTH_M:
        return np.inf
    fz = f / z
    u = x * fz + cu
    v = y * fz + cv
    du, dv = u - L[m, 0], v - L[m, 1]
    dur, dvr = u - b * fz - Rr[m, 0], v - Rr[m, 1]
    return max(du * du + dv * dv, dur * dur + dvr * dvr)


@njit(cache=True, nogil=True)
def max_errors(R: F64, t: F64, P: F64, L: F64, Rr: F64, f: float, cu: float, cv: float,
               b: float, err: F64) -> None:  # fmt: skip
    """``err`` (M,) px: the larger of the left and right pixel errors of points ``P`` (M, 3)
    moved by ``R`` (3, 3), ``t`` (3,) against pixels ``L``/``Rr`` (M, 2); inf for a point
    behind the camera or a non-finite error."""
    for m in range(P.shape[0]):
        e2 = _sq_error(R, t, P, L, Rr, m, f, cu, cv, b)
        err[m] = math.sqrt(e2) if np.isfinite(e2) else np.inf


@njit(cache=True, nogil=True)
def refine_select(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, W: F64, dvar: F64, use_dvar: bool, f: float,
    cu: float, cv: float, b: float, iterations: int, tol: float, rounds: int,
    inlier_px: float, err: F64,
) -> None:
    """RANSAC's final refinement of one motion ``R`` (3, 3), ``t`` (3,) (in place): Gauss-Newton
    (at most ``iterations``, down to ``tol``) on the features selected by ``W`` (M,) in {0, 1},
    then every feature whose larger left/right error is below ``inlier_px`` is selected
    (``W`` updated in place), repeated for at most ``rounds`` rounds until the selection stops
    changing. ``err`` (M,) receives the errors (px) of the last round."""
    A = np.zeros((6, 6))
    g = np.zeros(6)
    delta = np.zeros(6)
    for _ in range(max(rounds, 1)):
        _gauss_newton_one(R, t, P, L, Rr, W, dvar, use_dvar, f, cu, cv, b, iterations, tol,
                          A, g, delta)  # fmt: skip
        max_errors(R, t, P, L, Rr, f, cu, cv, b, err)
        same = True
        for m in range(P.shape[0]):
            w = 1.0 if err[m] < inlier_px else 0.0
            if w != W[m]:
                same = False
            W[m] = w
        if same:
            break


@njit(cache=True, nogil=True)
def normal_equations(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, W: F64, dvar: F64, use_dvar: bool, f: float,
    cu: float, cv: float, b: float,
) -> tuple[F64, F64, float]:
    """Normal matrix (6, 6), gradient (6,) and weighted squared error of one problem (tests)."""
    A = np.zeros((6, 6))
    g = np.zeros(6)
    cost = _accumulate(R, t, P, L, Rr, W, dvar, use_dvar, f, cu, cv, b, A, g)
    return A, g, cost


@njit(cache=True, nogil=True)
def score_batch(
    R: F64, t: F64, P: F64, L: F64, Rr: F64, f: float, cu: float, cv: float, b: float,
    inlier_px: float,
) -> tuple[F64, NDArray[np.bool_]]:
    """RANSAC score (H,) and inlier mask (H, M) of H motions on shared features ``P`` (M, 3),
    ``L``/``Rr`` (M, 2): inlier count minus a small penalty growing with the inliers' errors
    (the larger of the left and right pixel errors; ties go to the tighter fit)."""
    H, M = R.shape[0], P.shape[0]
    score = np.zeros(H)
    inl = np.zeros((H, M), dtype=np.bool_)
    thr2 = inlier_px * inlier_px
    for h in range(H):
        count = 0
        err = 0.0
        for m in range(M):
            e2 = _sq_error(R[h], t[h], P, L, Rr, m, f, cu, cv, b)
            if e2 < thr2:  # NaN never passes
                inl[h, m] = True
                count += 1
                err += math.sqrt(e2)
        score[h] = count - err / (inlier_px * (M + 1))
    return score, inl
