"""Compiled per-feature terms of the egomotion covariance (numba; ``egomotion_cov``).

For each feature: the residual Jacobian ``J`` (4x6) w.r.t. the motion (local rotation, then
translation), the estimator's weighted ``W J`` (identity minus the rank-one depth term), the
k-1 pixel factor ``G`` (4x3, eq. 10) and the whitened squared residual ``rᵀ (I + G Gᵀ)⁻¹ r``,
plus the sums ``Σ Jᵀ W J`` and ``Σ Jᵀ W (I + G Gᵀ) W J``. Written with numpy these are some 40
array operations on (M, 4, 6) arrays per frame, whose fixed cost made the covariance a third
of the RANSAC stage; the formulas are those documented in ``egomotion_cov``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@njit(cache=True, nogil=True)
def _feature_terms(
    R: F64, t: F64, p: F64, uvl: F64, uvr: F64, f: float, cu: float, cv: float, b: float,
    Jm: F64, Gm: F64, r: F64, ray: F64,
) -> None:
    """One feature at ``p`` (3,) m: residuals ``r`` (4,) px, Jacobian ``Jm`` (4, 6), k-1 pixel
    factor ``Gm`` (4, 3) and ``ray`` (4,) = (d residual / d p_Ckm1) p (all overwritten)."""
    x = R[0, 0] * p[0] + R[0, 1] * p[1] + R[0, 2] * p[2] + t[0]
    y = R[1, 0] * p[0] + R[1, 1] * p[1] + R[1, 2] * p[2] + t[1]
    z = R[2, 0] * p[0] + R[2, 1] * p[1] + R[2, 2] * p[2] + t[2]
    fz = f / z
    r[0] = x * fz + cu - uvl[0]
    r[1] = y * fz + cv - uvl[1]
    r[2] = (x - b) * fz + cu - uvr[0]
    r[3] = y * fz + cv - uvr[1]
    # Projection Jacobian P (4x3): rows left u, left v, right u, right v.
    P = np.zeros((4, 3))
    P[0, 0] = P[2, 0] = P[1, 1] = P[3, 1] = fz
    P[0, 2] = -fz * x / z
    P[1, 2] = P[3, 2] = -fz * y / z
    P[2, 2] = -fz * (x - b) / z
    zp = p[2]
    k_fb = zp / (f * b)
    for i in range(4):
        a0 = P[i, 0] * R[0, 0] + P[i, 1] * R[1, 0] + P[i, 2] * R[2, 0]  # (P R)[i, :]
        a1 = P[i, 0] * R[0, 1] + P[i, 1] * R[1, 1] + P[i, 2] * R[2, 1]
        a2 = P[i, 0] * R[0, 2] + P[i, 1] * R[1, 2] + P[i, 2] * R[2, 2]
        Jm[i, 0] = a2 * p[1] - a1 * p[2]
        Jm[i, 1] = a0 * p[2] - a2 * p[0]
        Jm[i, 2] = a1 * p[0] - a0 * p[1]
        Jm[i, 3] = P[i, 0]
        Jm[i, 4] = P[i, 1]
        Jm[i, 5] = P[i, 2]
        ray[i] = a0 * p[0] + a1 * p[1] + a2 * p[2]
        a = ray[i] * k_fb  # residual per px of u_r at k-1
        Gm[i, 0] = a0 * (zp / f) - a
        Gm[i, 1] = a1 * (zp / f)
        Gm[i, 2] = a


@njit(cache=True, nogil=True)
def covariance_terms(
    R: F64, t: F64, p: F64, uvl: F64, uvr: F64, s_e: F64, use_se: bool, f: float, cu: float,
    cv: float, b: float, J: F64, WJ: F64, G: F64, e2: F64, spread: F64, A: F64, B: F64,
) -> None:
    """Per feature m of ``p`` (M, 3) m (all in front of both cameras), pixels ``uvl``/``uvr``
    (M, 2) at k, motion ``R`` (3, 3), ``t`` (3,): ``J[m]`` (4, 6), ``WJ[m]`` (4, 6) (weights
    of the estimator, depth term ``s_e[m]`` m²/px² if ``use_se``), ``G[m]`` (4, 3),
    ``e2[m]`` px² the whitened squared residual for unit pixel noise, ``spread[m]``
    ``1 + max(|G_left|², |G_right|²)`` (Frobenius, 2x3 halves); ``A`` (6, 6) ``Σ Jᵀ W J`` and
    ``B`` (6, 6) ``Σ Jᵀ W (I + G Gᵀ) W J`` (all outputs overwritten)."""
    A[:, :] = 0.0
    B[:, :] = 0.0
    r = np.zeros(4)
    ray = np.zeros(4)
    ae = np.zeros(4)
    GtWJ = np.zeros((3, 6))
    M3 = np.zeros((3, 3))
    yv = np.zeros(3)
    for m in range(p.shape[0]):
        Jm, Gm, Wm = J[m], G[m], WJ[m]
        _feature_terms(R, t, p[m], uvl[m], uvr[m], f, cu, cv, b, Jm, Gm, r, ray)
        ce = 0.0
        ae[:] = 0.0
        if use_se:
            se = s_e[m] if np.isfinite(s_e[m]) else 0.0
            n2 = 0.0
            for i in range(4):
                ae[i] = ray[i] / p[m, 2]  # residual change per metre of depth at k-1
                n2 += ae[i] * ae[i]
            ce = se / (1.0 + se * n2)
        for j in range(6):
            aJ = ae[0] * Jm[0, j] + ae[1] * Jm[1, j] + ae[2] * Jm[2, j] + ae[3] * Jm[3, j]
            for i in range(4):
                Wm[i, j] = Jm[i, j] - ce * ae[i] * aJ
        for a in range(6):
            for c in range(a, 6):
                sa = 0.0
                sb = 0.0
                for i in range(4):
                    sa += Jm[i, a] * Wm[i, c]
                    sb += Wm[i, a] * Wm[i, c]
                A[a, c] += sa
                B[a, c] += sb
        for k in range(3):
            for j in range(6):
                s = 0.0
                for i in range(4):
                    s += Gm[i, k] * Wm[i, j]
                GtWJ[k, j] = s
            yv[k] = Gm[0, k] * r[0] + Gm[1, k] * r[1] + Gm[2, k] * r[2] + Gm[3, k] * r[3]
            for k2 in range(3):
                M3[k, k2] = (Gm[0, k] * Gm[0, k2] + Gm[1, k] * Gm[1, k2] + Gm[2, k] * Gm[2, k2]
                             + Gm[3, k] * Gm[3, k2] + (1.0 if k == k2 else 0.0))  # fmt: skip
        for a in range(6):
            for c in range(a, 6):
                B[a, c] += GtWJ[0, a] * GtWJ[0, c] + GtWJ[1, a] * GtWJ[1, c] + (
                    GtWJ[2, a] * GtWJ[2, c]
                )
        # rᵀ (I + G Gᵀ)⁻¹ r = |r|² - yᵀ (I + GᵀG)⁻¹ y, y = Gᵀ r (Woodbury; adjugate 3x3).
        a_, b_, c_ = M3[0, 0], M3[0, 1], M3[0, 2]
        d_, e_, f_ = M3[1, 1], M3[1, 2], M3[2, 2]
        i00, i01, i02 = d_ * f_ - e_ * e_, c_ * e_ - b_ * f_, b_ * e_ - c_ * d_
        i11, i12, i22 = a_ * f_ - c_ * c_, b_ * c_ - a_ * e_, a_ * d_ - b_ * b_
        det = a_ * i00 + b_ * i01 + c_ * i02
        q = i00 * yv[0] * yv[0] + i11 * yv[1] * yv[1] + i22 * yv[2] * yv[2]
        q += 2.0 * (i01 * yv[0] * yv[1] + i02 * yv[0] * yv[2] + i12 * yv[1] * yv[2])
        q /= det
        e2[m] = r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3] - q
        gl = gr = 0.0
        for k in range(3):
            gl += Gm[0, k] * Gm[0, k] + Gm[1, k] * Gm[1, k]
            gr += Gm[2, k] * Gm[2, k] + Gm[3, k] * Gm[3, k]
        spread[m] = 1.0 + max(gl, gr)
    for a in range(6):
        for c in range(a):
            A[a, c] = A[c, a]
            B[a, c] = B[c, a]


@njit(cache=True, nogil=True)
def sandwich(A: F64, B: F64, scale: float, out: F64) -> bool:
    """``out`` (6, 6) = ``scale`` sym(A⁻¹ B A⁻ᵀ) (sym: the mean with its transpose), ``A`` by
    Gauss-Jordan elimination with partial pivoting (a LAPACK call costs more than the
    arithmetic at this size). False (``out`` untouched) if ``A`` is singular to working
    precision."""
    n = A.shape[0]
    M = A.copy()
    Ai = np.eye(n)
    big = 0.0
    for i in range(n):
        for j in range(n):
            big = max(big, abs(A[i, j]))
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if not abs(M[p, c]) > 1e-14 * big:  # also false for NaN
            return False
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
                Ai[c, j], Ai[p, j] = Ai[p, j], Ai[c, j]
        d = 1.0 / M[c, c]
        for j in range(n):
            M[c, j] *= d
            Ai[c, j] *= d
        for r in range(n):
            if r != c and M[r, c] != 0.0:
                f = M[r, c]
                for j in range(n):
                    M[r, j] -= f * M[c, j]
                    Ai[r, j] -= f * Ai[c, j]
    T = Ai @ B
    C = T @ Ai.T
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * scale * (C[i, j] + C[j, i])
    return True
