"""Compiled per-feature loops of the two-frame bundle adjustment (numba).

The arithmetic is that of ``svains.frontend.egomotion_bundle`` (its module docstring gives the
model): inverse-depth points ``(α, β, ρ)`` anchored at the left camera at k-1, motion
``h = R (α, β, 1) + ρ t``, rotation updated on the right ``R <- R Exp(δθ)``. Each feature
costs a few dozen floating-point operations; written with numpy, the ~30 array calls per
Gauss-Newton step made a frame of 900 features cost 100 ms.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

MIN_HZ = 1e-9


@njit(cache=True, nogil=True)
def _feature(R: F64, t: F64, a: F64, zp: F64, zc: F64, f: float, b: float, cu: float,
             cv: float, r: F64, Jp: F64, Jx: F64) -> None:  # fmt: skip
    """Residuals ``r`` (8,) px (predicted minus measured: k-1 u_l, v_l, u_r, v_r, then k) and
    Jacobians ``Jp`` (8, 3) w.r.t. (α, β, ρ), ``Jx`` (4, 6) of the k rows w.r.t. (δθ, δt)."""
    al, be, rho = a[0], a[1], a[2]
    r[0] = f * al + cu - zp[0]
    r[1] = f * be + cv - zp[1]
    r[2] = f * (al - b * rho) + cu - zp[2]
    r[3] = f * be + cv - zp[3]
    h0 = R[0, 0] * al + R[0, 1] * be + R[0, 2] + rho * t[0]
    h1 = R[1, 0] * al + R[1, 1] * be + R[1, 2] + rho * t[1]
    h2 = R[2, 0] * al + R[2, 1] * be + R[2, 2] + rho * t[2]
    iz = 1.0 / max(h2, MIN_HZ)
    r[4] = f * h0 * iz + cu - zc[0]
    r[5] = f * h1 * iz + cv - zc[1]
    r[6] = f * (h0 - b * rho) * iz + cu - zc[2]
    r[7] = f * h1 * iz + cv - zc[3]
    # d(pixels at k) / dh, rows u_l, v_l, u_r (v_r = v_l).
    d00, d02 = f * iz, -f * h0 * iz * iz
    d11, d12 = f * iz, -f * h1 * iz * iz
    d22 = -f * (h0 - b * rho) * iz * iz
    for i in range(8):
        for j in range(3):
            Jp[i, j] = 0.0
    Jp[0, 0] = f
    Jp[1, 1] = f
    Jp[2, 0] = f
    Jp[2, 2] = -f * b
    Jp[3, 1] = f
    # dh / d(α, β, ρ) = [R[:, 0], R[:, 1], t].
    for j in range(3):
        c0 = R[0, j] if j < 2 else t[0]
        c1 = R[1, j] if j < 2 else t[1]
        c2 = R[2, j] if j < 2 else t[2]
        Jp[4, j] = d00 * c0 + d02 * c2
        Jp[5, j] = d11 * c1 + d12 * c2
        Jp[6, j] = d00 * c0 + d22 * c2
        Jp[7, j] = Jp[5, j]
    Jp[6, 2] -= f * b * iz
    # dh / dδθ = -R [a1]x with a1 = (α, β, 1); dh / dδt = ρ I.
    m0 = (-(R[0, 1] * 1.0 - R[0, 2] * be), -(R[0, 2] * al - R[0, 0] * 1.0),
          -(R[0, 0] * be - R[0, 1] * al))
    m1 = (-(R[1, 1] * 1.0 - R[1, 2] * be), -(R[1, 2] * al - R[1, 0] * 1.0),
          -(R[1, 0] * be - R[1, 1] * al))
    m2 = (-(R[2, 1] * 1.0 - R[2, 2] * be), -(R[2, 2] * al - R[2, 0] * 1.0),
          -(R[2, 0] * be - R[2, 1] * al))
    for j in range(3):
        Jx[0, j] = d00 * m0[j] + d02 * m2[j]
        Jx[1, j] = d11 * m1[j] + d12 * m2[j]
        Jx[2, j] = d00 * m0[j] + d22 * m2[j]
        Jx[3, j] = Jx[1, j]
    for j in range(3):
        e0 = rho if j == 0 else 0.0
        e1 = rho if j == 1 else 0.0
        e2 = rho if j == 2 else 0.0
        Jx[0, 3 + j] = d00 * e0 + d02 * e2
        Jx[1, 3 + j] = d11 * e1 + d12 * e2
        Jx[2, 3 + j] = d00 * e0 + d22 * e2
        Jx[3, 3 + j] = Jx[1, 3 + j]


@njit(cache=True, nogil=True)
def _inv3(H: F64, out: F64) -> bool:
    """Inverse of a symmetric 3x3 ``H`` into ``out``; False when singular."""
    c00 = H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1]
    c01 = H[1, 2] * H[2, 0] - H[1, 0] * H[2, 2]
    c02 = H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0]
    det = H[0, 0] * c00 + H[0, 1] * c01 + H[0, 2] * c02
    if not (abs(det) > 1e-300):
        return False
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (H[0, 2] * H[2, 1] - H[0, 1] * H[2, 2]) * inv
    out[1, 1] = (H[0, 0] * H[2, 2] - H[0, 2] * H[2, 0]) * inv
    out[2, 1] = (H[0, 1] * H[2, 0] - H[0, 0] * H[2, 1]) * inv
    out[0, 2] = (H[0, 1] * H[1, 2] - H[0, 2] * H[1, 1]) * inv
    out[1, 2] = (H[0, 2] * H[1, 0] - H[0, 0] * H[1, 2]) * inv
    out[2, 2] = (H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]) * inv
    return True


@njit(cache=True, nogil=True)
def reduced_system(
    R: F64, t: F64, a: F64, zp: F64, zc: F64, sel: I64, f: float, b: float, cu: float,
    cv: float, S: F64, s: F64, Hi: F64, Hpx: F64, gp: F64,
) -> float:
    """The points' Schur complement over the features ``sel``: ``S`` (6, 6) and ``s`` (6,)
    (so that ``S δx = -s``), and per selected feature ``Hi`` (M, 3, 3) = Hpp⁻¹, ``Hpx``
    (M, 3, 6), ``gp`` (M, 3) for the back-substitution. Returns the summed squared residual
    (px²), or -1 when a point's block is singular."""
    r = np.empty(8)
    Jp = np.empty((8, 3))
    Jx = np.empty((4, 6))
    H = np.empty((3, 3))
    for i in range(6):
        s[i] = 0.0
        for j in range(6):
            S[i, j] = 0.0
    cost = 0.0
    for m in range(sel.size):
        k = sel[m]
        _feature(R, t, a[k], zp[k], zc[k], f, b, cu, cv, r, Jp, Jx)
        for i in range(8):
            cost += r[i] * r[i]
        for i in range(3):
            g = 0.0
            for q in range(8):
                g += Jp[q, i] * r[q]
            gp[m, i] = g
            for j in range(3):
                acc = 0.0
                for q in range(8):
                    acc += Jp[q, i] * Jp[q, j]
                H[i, j] = acc
            for j in range(6):
                acc = 0.0
                for q in range(4):
                    acc += Jp[4 + q, i] * Jx[q, j]
                Hpx[m, i, j] = acc
        if not _inv3(H, Hi[m]):
            return -1.0
        for i in range(6):
            g = 0.0
            for q in range(4):
                g += Jx[q, i] * r[4 + q]
            s[i] += g
            for j in range(i, 6):
                acc = 0.0
                for q in range(4):
                    acc += Jx[q, i] * Jx[q, j]
                S[i, j] += acc
        # Minus Hpxᵀ Hpp⁻¹ Hpx and Hpxᵀ Hpp⁻¹ gp.
        Hm, Pm = Hi[m], Hpx[m]
        for i in range(6):
            w0 = Hm[0, 0] * Pm[0, i] + Hm[0, 1] * Pm[1, i] + Hm[0, 2] * Pm[2, i]
            w1 = Hm[1, 0] * Pm[0, i] + Hm[1, 1] * Pm[1, i] + Hm[1, 2] * Pm[2, i]
            w2 = Hm[2, 0] * Pm[0, i] + Hm[2, 1] * Pm[1, i] + Hm[2, 2] * Pm[2, i]
            s[i] -= w0 * gp[m, 0] + w1 * gp[m, 1] + w2 * gp[m, 2]
            for j in range(i, 6):
                S[i, j] -= w0 * Hpx[m, 0, j] + w1 * Hpx[m, 1, j] + w2 * Hpx[m, 2, j]
    for i in range(6):
        for j in range(i):
            S[i, j] = S[j, i]
    return cost


@njit(cache=True, nogil=True)
def back_substitute(a: F64, sel: I64, dx: F64, Hi: F64, Hpx: F64, gp: F64) -> None:
    """Point updates ``δa = -Hpp⁻¹ (gp + Hpx δx)`` of the features ``sel``, applied in place."""
    for m in range(sel.size):
        k = sel[m]
        v = np.empty(3)
        for i in range(3):
            acc = gp[m, i]
            for j in range(6):
                acc += Hpx[m, i, j] * dx[j]
            v[i] = acc
        for i in range(3):
            a[k, i] -= Hi[m, i, 0] * v[0] + Hi[m, i, 1] * v[1] + Hi[m, i, 2] * v[2]


@njit(cache=True, nogil=True)
def refine_points(R: F64, t: F64, a: F64, zp: F64, zc: F64, f: float, b: float, cu: float,
                  cv: float, steps: int, e2: F64) -> None:  # fmt: skip
    """Every point refined for the fixed motion (``steps`` 3x3 Gauss-Newton steps each, in
    place); ``e2`` (N,) its squared residual after (px², inf when its block is singular)."""
    r = np.empty(8)
    Jp = np.empty((8, 3))
    Jx = np.empty((4, 6))
    H = np.empty((3, 3))
    Hinv = np.empty((3, 3))
    g = np.empty(3)
    for k in range(a.shape[0]):
        ok = True
        for _ in range(steps):
            _feature(R, t, a[k], zp[k], zc[k], f, b, cu, cv, r, Jp, Jx)
            for i in range(3):
                acc = 0.0
                for q in range(8):
                    acc += Jp[q, i] * r[q]
                g[i] = acc
                for j in range(3):
                    acc = 0.0
                    for q in range(8):
                        acc += Jp[q, i] * Jp[q, j]
                    H[i, j] = acc
            if not _inv3(H, Hinv):
                ok = False
                break
            for i in range(3):
                a[k, i] -= Hinv[i, 0] * g[0] + Hinv[i, 1] * g[1] + Hinv[i, 2] * g[2]
        if not ok:
            e2[k] = np.inf
            continue
        _feature(R, t, a[k], zp[k], zc[k], f, b, cu, cv, r, Jp, Jx)
        acc = 0.0
        for i in range(8):
            acc += r[i] * r[i]
        e2[k] = acc
