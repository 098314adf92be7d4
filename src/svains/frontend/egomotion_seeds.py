"""Compiled RANSAC hypotheses of the stereo egomotion (numba): 3-point rigid alignment seeds,
refined by Gauss-Newton on their triple, in one call per frame.

Written with numpy, drawing the triples' points, aligning them, adding the prior's two
hypotheses and refining took some 30 array calls per frame, more than the arithmetic itself
(51 problems of 3 points). The random draws stay in numpy (``egomotion._hypotheses``), so the
hypotheses are those of the same seed.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from svains.frontend.egomotion_kernels import gauss_newton_batch

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@njit(cache=True, nogil=True)
def align_batch(P: F64, C: F64, R: F64, t: F64) -> None:
    """Rigid alignment ``C ≈ R P + t`` of H point sets ``P``/``C`` (H, M, 3) into ``R`` (H, 3, 3),
    ``t`` (H, 3) (least squares; Horn's unit-quaternion method). The quaternion is the dominant
    eigenvector of Horn's 4x4 matrix, found by repeated squaring of the matrix shifted to be
    positive semi-definite (2^16-th power; no LAPACK call). Sets with a non-finite point get the
    identity."""
    H, M = P.shape[0], P.shape[1]
    N = np.zeros((4, 4))
    Q = np.zeros((4, 4))
    Q2 = np.zeros((4, 4))
    ma = np.zeros(3)
    mb = np.zeros(3)
    S = np.zeros((3, 3))
    for h in range(H):
        finite = True
        ma[:] = 0.0
        mb[:] = 0.0
        for m in range(M):
            for i in range(3):
                if not (np.isfinite(P[h, m, i]) and np.isfinite(C[h, m, i])):
                    finite = False
                ma[i] += P[h, m, i] / M
                mb[i] += C[h, m, i] / M
        if not finite:
            for i in range(3):
                for j in range(3):
                    R[h, i, j] = 1.0 if i == j else 0.0
                t[h, i] = 0.0
            continue
        S[:, :] = 0.0  # S[a, b] = Σ (p_a - μ_a)(c_b - μ_b)
        for m in range(M):
            for i in range(3):
                for j in range(3):
                    S[i, j] += (P[h, m, i] - ma[i]) * (C[h, m, j] - mb[j])
        sxx, sxy, sxz = S[0, 0], S[0, 1], S[0, 2]
        syx, syy, syz = S[1, 0], S[1, 1], S[1, 2]
        szx, szy, szz = S[2, 0], S[2, 1], S[2, 2]
        N[0, 0], N[0, 1], N[0, 2], N[0, 3] = sxx + syy + szz, syz - szy, szx - sxz, sxy - syx
        N[1, 1], N[1, 2], N[1, 3] = sxx - syy - szz, sxy + syx, szx + sxz
        N[2, 2], N[2, 3] = -sxx + syy - szz, syz + szy
        N[3, 3] = -sxx - syy + szz
        for i in range(4):
            for j in range(i):
                N[i, j] = N[j, i]
        # Shift by the Frobenius norm (a bound on the spectral radius): eigenvalues >= 0.
        shift = 0.0
        for i in range(4):
            for j in range(4):
                shift += N[i, j] * N[i, j]
        shift = max(math.sqrt(shift), 1e-300)
        for i in range(4):
            for j in range(4):
                Q[i, j] = N[i, j] + (shift if i == j else 0.0)
        for _ in range(16):  # Q <- Q² / max|Q|: converges to the dominant eigenprojector
            nrm = 0.0
            for i in range(4):
                for j in range(4):
                    v = (Q[i, 0] * Q[0, j] + Q[i, 1] * Q[1, j] + Q[i, 2] * Q[2, j]
                         + Q[i, 3] * Q[3, j])
                    Q2[i, j] = v
                    nrm = max(nrm, abs(v))
            nrm = max(nrm, 1e-300)
            for i in range(4):
                for j in range(4):
                    Q[i, j] = Q2[i, j] / nrm
        best, col = -1.0, 0
        for j in range(4):
            s = Q[0, j] ** 2 + Q[1, j] ** 2 + Q[2, j] ** 2 + Q[3, j] ** 2
            if s > best:
                best, col = s, j
        nq = math.sqrt(best)
        w, x, y, z = Q[0, col] / nq, Q[1, col] / nq, Q[2, col] / nq, Q[3, col] / nq
        R[h, 0, 0] = 1 - 2 * (y * y + z * z)
        R[h, 0, 1] = 2 * (x * y - w * z)
        R[h, 0, 2] = 2 * (x * z + w * y)
        R[h, 1, 0] = 2 * (x * y + w * z)
        R[h, 1, 1] = 1 - 2 * (x * x + z * z)
        R[h, 1, 2] = 2 * (y * z - w * x)
        R[h, 2, 0] = 2 * (x * z - w * y)
        R[h, 2, 1] = 2 * (y * z + w * x)
        R[h, 2, 2] = 1 - 2 * (x * x + y * y)
        for i in range(3):
            t[h, i] = mb[i] - (R[h, i, 0] * ma[0] + R[h, i, 1] * ma[1] + R[h, i, 2] * ma[2])


@njit(cache=True, nogil=True)
def triple_hypotheses(
    P: F64, L: F64, Rr: F64, C: F64, use_c: bool, triples: I64, R_prior: F64, t_prior: F64,
    use_prior: bool, iterations: int, f: float, cu: float, cv: float, b: float, Rh: F64,
    th: F64,
) -> None:
    """Motions ``Rh`` (H', 3, 3), ``th`` (H', 3) (overwritten) from the rows of ``triples``
    (H, 3) indices into points ``P`` (N, 3) m at k-1, pixels ``L``/``Rr`` (N, 2) at k: each
    row's Gauss-Newton fit (``iterations``) on its 3 features, started from the rigid alignment
    of its points at k ``C`` (N, 3) (``use_c``; otherwise, or with a non-finite point, the
    identity). With ``use_prior`` the last row of ``triples`` starts from the prior
    ``R_prior``/``t_prior`` instead, and the prior itself, unrefined, is appended
    (H' = H + 1; otherwise H' = H)."""
    H = triples.shape[0]
    n_seed = H - 1 if use_prior else H
    P3 = np.empty((H, 3, 3))
    C3 = np.empty((H, 3, 3))
    L3 = np.empty((H, 3, 2))
    R3 = np.empty((H, 3, 2))
    for h in range(H):
        for k in range(3):
            i = triples[h, k]
            for j in range(3):
                P3[h, k, j] = P[i, j]
                C3[h, k, j] = C[i, j]
            for j in range(2):
                L3[h, k, j] = L[i, j]
                R3[h, k, j] = Rr[i, j]
    R0 = np.empty((H, 3, 3))
    t0 = np.zeros((H, 3))
    if use_c:
        align_batch(P3[:n_seed], C3[:n_seed], R0[:n_seed], t0[:n_seed])
    else:
        for h in range(n_seed):
            for i in range(3):
                for j in range(3):
                    R0[h, i, j] = 1.0 if i == j else 0.0
    if use_prior:
        R0[H - 1] = R_prior
        t0[H - 1] = t_prior
    gauss_newton_batch(R0, t0, P3, L3, R3, np.ones((H, 3)), np.zeros((H, 3)), False, f, cu, cv,
                       b, iterations, 1e-9)  # fmt: skip
    Rh[:H] = R0
    th[:H] = t0
    if use_prior:
        Rh[H] = R_prior
        th[H] = t_prior
