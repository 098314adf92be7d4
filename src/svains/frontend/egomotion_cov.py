"""Covariance of the stereo egomotion from the noise of all four pixels of every feature.

Motion ``T_Ck_Ckm1``: ``p_Ck = R p_Ckm1 + t``. Feature i was triangulated at k-1 from its left and
right pixels (eq. 10, ``RectifiedStereo.triangulate``) and is measured again at k in both images,
so its 4 residuals (left u, v, right u, v at k, px) carry

- the pixel noise at k directly: ``σ² I₄``;
- the pixel noise at k-1 through the triangulated point: ``σ² G Gᵀ`` with
  ``G = (d residual / d p_Ckm1) (d p_Ckm1 / d (u_l, v_l, u_r)_{k-1})`` (4x3; eq. 10 does not use
  the right row ``v_r`` at k-1, so its noise does not reach the point).

``Sᵢ = σ² (I₄ + Gᵢ Gᵢᵀ)`` is each feature's residual covariance. The estimator (RANSAC +
Gauss-Newton in ``egomotion.py``) does not weight with ``Sᵢ``: it uses its own weights ``Wᵢ``
(identity plus a rank-one depth term) and keeps only features whose left and right errors are
both below the inlier gate ``c``. Its covariance is therefore the M-estimator sandwich

    Σ = A⁻¹ B A⁻ᵀ,   A = Σᵢ Jᵢᵀ Wᵢ Kᵢ Sᵢ⁻¹ Jᵢ,   B = Σᵢ Jᵢᵀ Wᵢ Kᵢ Wᵢ Jᵢ,

with ``Jᵢ`` (4x6) the residual Jacobian w.r.t. the motion and ``Kᵢ = E[r rᵀ 1{gate}]`` the
second moment of the residual that survives the gate. Without a gate ``Kᵢ = Sᵢ`` and this is the
usual sandwich ``(JᵀWJ)⁻¹ JᵀWSWJ (JᵀWJ)⁻¹``. With a gate the fit is pulled toward features that
agree with it: by Stein's lemma ``E[d(r 1{gate})/dr] = Kᵢ Sᵢ⁻¹``, which is what shrinks ``A``
(in one dimension a gate at one standard deviation gives 5.0 σ²/n against the 1.5 σ²/n of the
survivors' normal matrix). ``Kᵢ`` is integrated with a fixed set of normal samples, and only for
features whose residual spread reaches the gate. The robust noise estimate is corrected the
same way (the survivors of a gate look less noisy than the noise is).

Measured (Monte Carlo with exact geometry, ``tests/test_frontend_egomotion_cov.py``): mean NEES
5.7-5.9 at 0.2 px; with a 0.5 px noise the gate model gives 4.3-7.1 where ignoring the gate
gives 10-20. Left out: errors shared by all features of a frame. On the simulated village
images (``bench/eval_frontend_sim.py``) the white KLT noise is 0.1 px, but the egomotion error
is ~9x larger in variance than that predicts (translation along the motion 0.9 % rms per
frame, partly pulled toward the motion prediction that seeds KLT), hence
``RansacOptions.cov_inflation`` (a floor on the effective pixel variance, measured). Also left
out: an estimate that is not the fixed point of the gated fit. With ``features0`` (0.5 px) the
1.5 px gate cuts ~40 % of the village features and two select-refine rounds stop short of it:
NEES 22-27 (30 s, seeds 0, 1, 3); iterating the rounds until the selection repeats gives 4.7
and 3x smaller translation errors (seed 0).

The rotation error is local, ``R = R̂ Exp(δθ)`` (docs/conventions.md): ``dq/dδθ = -R [p]×``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from svains.frontend import egomotion_cov_kernels as ck
from svains.geometry.camera import RectifiedStereo

F64 = NDArray[np.float64]

_MIN_DEPTH_M = 1e-3
# Median of a chi-square with 4 degrees of freedom: turns the median whitened squared residual
# into a variance estimate that ignores outliers.
_CHI2_4_MEDIAN = 3.356694
# Normal samples for the gated moment: a different set of 32 (plus their negatives, so odd
# moments vanish exactly) for each of 512 features in turn, so sampling errors average out
# over the features instead of repeating.
_POOL = np.random.default_rng(20140601).standard_normal((512, 32, 4))
_POOL = np.concatenate([_POOL, -_POOL], axis=1)
# A feature whose largest 2-D residual variance is below gate² / this is (nearly) never cut:
# P(cut) < 0.3 % even with all of the spread along one axis; its gated moment is taken as S.
_INACTIVE_RATIO = 9.0
_ROBUST_FEATURES = 96
_ROBUST_TAKEOVER = 1.5
_I3, _I4 = np.eye(3), np.eye(4)


@lru_cache(maxsize=64)
def _spread(m: int, k: int) -> NDArray[np.int64]:
    """``k`` indices spread evenly over [0, m) (``np.linspace`` truncated; cached: the same
    few sizes come back every frame)."""
    out = np.linspace(0, m - 1, k).astype(np.int64)
    out.flags.writeable = False
    return out


def _inv3_sym(M: F64) -> F64:
    """Inverse of symmetric positive-definite 3x3 matrices (M, 3, 3), written out (adjugate)."""
    a, b, c = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    d, e, f = M[:, 1, 1], M[:, 1, 2], M[:, 2, 2]
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    out = np.empty_like(M)
    out[:, 0, 0] = A
    out[:, 0, 1] = out[:, 1, 0] = B
    out[:, 0, 2] = out[:, 2, 0] = C
    out[:, 1, 1] = a * f - c * c
    out[:, 1, 2] = out[:, 2, 1] = b * c - a * e
    out[:, 2, 2] = a * d - b * b
    return out / (a * A + b * B + c * C)[:, None, None]


def _unit_samples(S: F64) -> tuple[F64, F64]:
    """Standard normal samples ``Z`` (M, 64, 4), one set of the pool per feature, and the
    residual samples ``r = L Z`` with covariance ``S = L Lᵀ`` (M, 4, 4) they give
    (``rᵀ S⁻¹ r = |Z|²``)."""
    Z = _POOL[np.arange(S.shape[0]) % _POOL.shape[0]]
    return Z, Z @ np.swapaxes(np.linalg.cholesky(S), 1, 2)


def _gate_mask(r: F64, c: float) -> NDArray[np.bool_]:
    """Samples (M, K, 4) whose left (0-1) and right (2-3) 2-D errors are both below ``c``."""
    r2 = r * r
    return (r2[..., 0] + r2[..., 1] < c * c) & (r2[..., 2] + r2[..., 3] < c * c)


def _gated_second_moment(r: F64, c: float) -> F64:
    """``E[r rᵀ 1{|r_l| < c and |r_r| < c}]`` (M, 4, 4) from samples ``r`` (M, K, 4)."""
    rg = r * _gate_mask(r, c)[..., None]
    return np.swapaxes(rg, 1, 2) @ r / r.shape[1]


def _truncated_sigma2(e2: F64, Z: F64, r: F64, gate_px: float, s2: float) -> float:
    """Pixel variance whose gated residuals have the observed median whitened squared residual
    ``e2`` (M,) px²: survivors of the gate look less noisy than the noise is, so the plain
    median under-estimates σ² when the gate cuts many features. Fixed point of
    ``σ² = median(e2) / median(χ² of samples surviving the gate at σ)``, from ``s2``; ``Z``,
    ``r`` from ``_unit_samples``."""
    z2 = (Z * Z).sum(-1)
    med = _median(e2)
    for _ in range(4):
        g = _gate_mask(r, gate_px / np.sqrt(s2))
        if not g.any():
            break
        s2 = med / float(np.median(z2[g]))
    return s2


def _stereo_residuals(q: F64, uvl: F64, uvr: F64, rig: RectifiedStereo) -> F64:
    """Predicted minus measured pixels (M, 4) ``(u_l, v_l, u_r, v_r)`` of moved points ``q``
    (M, 3) in C_k against the rectified pixels ``uvl``/``uvr`` (M, 2) (eq. 10's projection
    written out: it runs on every frame, and ``rig.project`` twice cost 3x as much)."""
    fz = rig.f / q[:, 2]
    r = np.empty((q.shape[0], 4))
    r[:, 0] = q[:, 0] * fz + rig.cu - uvl[:, 0]
    r[:, 1] = q[:, 1] * fz + rig.cv - uvl[:, 1]
    r[:, 2] = (q[:, 0] - rig.baseline) * fz + rig.cu - uvr[:, 0]
    r[:, 3] = q[:, 1] * fz + rig.cv - uvr[:, 1]
    return r


def _median(x: F64) -> float:
    """``np.median`` of a short finite 1-D array, without its generic-axis overhead."""
    s = np.sort(x)
    n = s.size
    return float(0.5 * (s[(n - 1) // 2] + s[n // 2]))


def _projection_jacobian(q: F64, f: float, b: float) -> F64:
    """d (u_l, v_l, u_r, v_r) / d q (M, 4, 3) of the stereo projection at points ``q`` (M, 3)."""
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    fz = f / z
    P = np.zeros((q.shape[0], 4, 3))
    P[:, 0, 0] = P[:, 2, 0] = P[:, 1, 1] = P[:, 3, 1] = fz
    P[:, 0, 2] = -fz * x / z
    P[:, 1, 2] = P[:, 3, 2] = -fz * y / z
    P[:, 2, 2] = -fz * (x - b) / z
    return P


def _previous_pixel_factor(PR: F64, p: F64, f: float, b: float) -> tuple[F64, F64]:
    """``G`` (M, 4, 3): residual change per pixel (u_l, v_l, u_r) at k-1 through the
    triangulation (eq. 10), from ``PR`` = d residual / d p_Ckm1 (M, 4, 3) and the points ``p``
    (M, 3); also ``PR p`` (M, 4) (the residual change along each point's ray, times its depth).

    d p/d u_r = p z/(f b) (along the ray), d p/d u_l = (z/f, 0, 0) - p z/(f b),
    d p/d v_l = (0, z/f, 0)."""
    zp = p[:, 2]
    ray = (PR @ p[:, :, None])[..., 0]
    a = ray * (zp / (f * b))[:, None]  # residual per px of u_r at k-1
    G = np.empty((p.shape[0], 4, 3))
    G[:, :, 0] = PR[..., 0] * (zp / f)[:, None] - a
    G[:, :, 1] = PR[..., 1] * (zp / f)[:, None]
    G[:, :, 2] = a
    return G, ray


def egomotion_covariance(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo,
    pixel_sigma_px: float, *, robust: bool = False, inflation: float = 1.0,
    estimator_depth_var_px2: F64 | None = None, gate_px: float | None = None,
) -> F64:
    """(6, 6) covariance of (local rotation vector [rad], translation [m]) of a motion estimate.

    ``R`` (3, 3), ``t`` (3,): the estimate ``T_Ck_Ckm1``; ``p_prev`` (M, 3) m: the inlier points
    in C_{k-1}, triangulated from their pixels at k-1 (eq. 10); ``uv_left``/``uv_right`` (M, 2)
    px: their rectified pixels at k. ``pixel_sigma_px``: standard deviation of every pixel
    coordinate at both times. ``robust``: a robust estimate from the median whitened residual
    replaces it when more than 1.5x larger in variance (below that, taking the larger of two
    would bias the covariance up by the estimate's own scatter). ``inflation``: floor on the
    effective pixel variance, in units of ``pixel_sigma_px²`` (errors shared by the features,
    which the model leaves out). ``estimator_depth_var_px2`` (M,): the rank-one depth weights
    the estimator used (depth variance over pixel variance, m²/px²; None: unit weights).
    ``gate_px``: the estimator's inlier limit on the left and right 2-D errors (None: no gate).
    Points behind either camera are ignored; with fewer than 3 usable points the diagonal is
    infinite.
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    p = np.asarray(p_prev, dtype=float).reshape(-1, 3)
    uvl = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    uvr = np.asarray(uv_right, dtype=float).reshape(-1, 2)
    s_e = None
    if estimator_depth_var_px2 is not None:
        s_e = np.asarray(estimator_depth_var_px2, dtype=float).reshape(-1)
    f, b = rig.f, rig.baseline
    q = p @ R.T + t  # moved points in C_k (M, 3)
    ok = (p[:, 2] > _MIN_DEPTH_M) & (q[:, 2] > _MIN_DEPTH_M)
    ok &= np.isfinite(q).all(1) & np.isfinite(uvl).all(1) & np.isfinite(uvr).all(1)
    if ok.sum() < 3:
        return np.diag(np.full(6, np.inf))
    if not ok.all():
        p, q, uvl, uvr = p[ok], q[ok], uvl[ok], uvr[ok]
        s_e = None if s_e is None else s_e[ok]
    m = p.shape[0]
    c_ = np.ascontiguousarray
    J, WJ, G = np.empty((m, 4, 6)), np.empty((m, 4, 6)), np.empty((m, 4, 3))
    e2, spread, A, B = np.empty(m), np.empty(m), np.empty((6, 6)), np.empty((6, 6))
    # J, W J, G, whitened residuals, Σ Jᵀ W J and Σ Jᵀ W S W J (compiled, one call).
    ck.covariance_terms(
        c_(R), c_(t), c_(p), c_(uvl), c_(uvr), e2 if s_e is None else c_(s_e), s_e is not None,
        f, rig.cu, rig.cv, b, J, WJ, G, e2, spread, A, B,
    )
    sigma2 = pixel_sigma_px**2
    if robust:
        # On at most _ROBUST_FEATURES features spread over the set: a median needs no more.
        sub = _spread(m, min(m, _ROBUST_FEATURES))
        s2 = _median(e2[sub]) / _CHI2_4_MEDIAN
        # Only a noise comparable to the gate is truncated noticeably: then correct for it.
        if gate_px is not None and s2 > sigma2 and 4.0 * s2 * _INACTIVE_RATIO > gate_px**2:
            Gs = G[sub]
            s2 = _truncated_sigma2(e2[sub], *_unit_samples(Gs @ np.swapaxes(Gs, 1, 2) + _I4),
                                   gate_px, s2)  # fmt: skip
        if s2 > _ROBUST_TAKEOVER * sigma2:
            sigma2 = s2
    if gate_px is not None:
        c = gate_px / np.sqrt(sigma2)  # gate in units of σ
        # Features whose 2-D residual spread stays far below the gate keep K = S (and add the
        # plain terms above); the others swap them for the gated ones.
        act = np.flatnonzero(spread * _INACTIVE_RATIO > c * c)
        if act.size:
            Ga, Ja, WJa = G[act], J[act], WJ[act]
            Gat = np.swapaxes(Ga, 1, 2)
            Sa = Ga @ Gat + _I4
            K = _gated_second_moment(_unit_samples(Sa)[1], c)
            SiJ = Ja - Ga @ (_inv3_sym(Gat @ Ga + _I3) @ (Gat @ Ja))  # S⁻¹ J (Woodbury)
            KWJ = (K @ WJa).reshape(-1, 6)
            WJa_f = WJa.reshape(-1, 6)
            A += KWJ.T @ SiJ.reshape(-1, 6) - Ja.reshape(-1, 6).T @ WJa_f  # Σ Jᵀ W K S⁻¹ J
            B += WJa_f.T @ KWJ - WJa_f.T @ (Sa @ WJa).reshape(-1, 6)
    # ``inflation`` floors the effective pixel variance at inflation σ² (errors shared by the
    # features); a white noise measured above that floor (robust) takes over.
    scale = max(sigma2, inflation * pixel_sigma_px**2)
    cov = np.empty((6, 6))
    if not ck.sandwich(A, B, scale, cov):  # singular: pseudo-inverse
        Ai = np.linalg.pinv(A)
        cov = scale * (Ai @ B @ Ai.T)
        cov = 0.5 * (cov + cov.T)
    return cov


def whitened_residuals(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo
) -> F64:
    """``rᵢᵀ (I + Gᵢ Gᵢᵀ)⁻¹ rᵢ`` (M,) px²: each feature's squared residual at motion ``R``, ``t``
    whitened by the four-pixel noise model for unit pixel noise (same inputs as
    ``egomotion_covariance``; NaN for points behind a camera). At the true motion its median over
    features divided by the chi-square(4) median (3.357) estimates the pixel variance σ²."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p_prev, dtype=float).reshape(-1, 3)
    q = p @ R.T + np.asarray(t, dtype=float)
    # Points behind either camera: NaN depth, so NaN rows below.
    q = np.where(((q[:, 2] > _MIN_DEPTH_M) & (p[:, 2] > _MIN_DEPTH_M))[:, None], q, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = _stereo_residuals(q, np.asarray(uv_left, float), np.asarray(uv_right, float), rig)
        G, _ = _previous_pixel_factor(_projection_jacobian(q, rig.f, rig.baseline) @ R, p,
                                      rig.f, rig.baseline)  # fmt: skip
        S = G @ np.swapaxes(G, 1, 2) + np.eye(4)
        good = np.isfinite(S).all((1, 2)) & np.isfinite(r).all(1)
        out = np.full(p.shape[0], np.nan)
        if good.any():
            sol = np.linalg.solve(S[good], r[good][..., None])[..., 0]
            out[good] = np.einsum("mi,mi->m", r[good], sol)
    return out
