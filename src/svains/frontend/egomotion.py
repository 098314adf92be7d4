"""Stereo egomotion and outlier rejection (paper eqs. 11-12), pure numpy and batched.

Motion ``T_Ck_Ckm1``: ``p_Ck = R p_Ckm1 + t``. A feature triangulated at k-1 (eq. 10) predicts its
left and right pixels at k; Gauss-Newton minimises the stereo reprojection error (eq. 12) over the
six motion parameters. RANSAC fits about 50 random triples *at once* (one batched Gauss-Newton),
keeps the hypothesis with most inliers, and refines on all its inliers.

During Gauss-Newton the rotation is updated on the left, ``R <- Exp(δθ) R``; the reported
covariance is converted to the project's local convention ``R = R̂ Exp(δθ)`` (docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]

_MIN_DEPTH_M = 1e-3


@dataclass(frozen=True)
class RansacOptions:
    """RANSAC/Gauss-Newton settings: ``iterations`` random triples; ``inlier_px`` limit on the
    larger of the left and right reprojection errors; ``gn_iterations`` per hypothesis and for the
    refinement; ``min_inliers`` for a motion measurement; ``seed`` of the sampler;
    ``depth_weighting`` models each point's depth uncertainty at k-1 (stereo matching noise equal
    to the pixel noise in each image) in the refinement and the covariance."""

    iterations: int = 50
    inlier_px: float = 1.5
    gn_iterations: int = 4
    refine_iterations: int = 5
    min_inliers: int = 8
    seed: int = 0
    depth_weighting: bool = True


@dataclass(frozen=True)
class EgomotionResult:
    """Best motion (``None`` if none), inlier mask (N,), per-feature max reprojection error
    (N,) px (left or right, whichever is larger)."""

    egomotion: Egomotion | None
    inlier: Bool
    error_px: F64


def reprojection_residuals(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo
) -> tuple[F64, F64]:
    """Residuals (H, M, 4) px (left u, v, right u, v; predicted minus measured) and the moved
    points (H, M, 3) for motions ``R`` (H, 3, 3), ``t`` (H, 3) and points ``p_prev`` (H, M, 3)."""
    q = p_prev @ np.swapaxes(R, 1, 2) + t[:, None, :]
    z = q[..., 2]
    zs = np.where(z > _MIN_DEPTH_M, z, np.nan)
    ul = rig.f * q[..., 0] / zs + rig.cu
    vl = rig.f * q[..., 1] / zs + rig.cv
    ur = rig.f * (q[..., 0] - rig.baseline) / zs + rig.cu
    r = np.stack(
        [ul - uv_left[..., 0], vl - uv_left[..., 1], ur - uv_right[..., 0], vl - uv_right[..., 1]],
        axis=-1,
    )
    return r, q


def _jacobian(q: F64, t: F64, rig: RectifiedStereo) -> F64:
    """d residual / d (δθ, δt), (H, M, 4, 6), at moved points ``q`` (H, M, 3)."""
    x, y = q[..., 0], q[..., 1]
    z = np.where(q[..., 2] > _MIN_DEPTH_M, q[..., 2], np.nan)
    fz = rig.f / z
    # Projection Jacobians d(u, v)/dq, rows: left u, left v, right u, right v (right: x - b).
    Jp = np.zeros((*q.shape[:-1], 4, 3))
    Jp[..., 0, 0] = fz
    Jp[..., 0, 2] = -fz * x / z
    Jp[..., 1, 1] = fz
    Jp[..., 1, 2] = -fz * y / z
    Jp[..., 2, 0] = fz
    Jp[..., 2, 2] = -fz * (x - rig.baseline) / z
    Jp[..., 3, :] = Jp[..., 1, :]
    # q = Exp(δθ) R p + t + δt: dq/dδθ = -[R p]x, so each row a^T maps to (R p) x a; dq/dδt = I.
    Rp = (q - t[:, None, :])[..., None, :]
    J = np.empty((*q.shape[:-1], 4, 6))
    J[..., :3] = np.cross(np.broadcast_to(Rp, Jp.shape), Jp)
    J[..., 3:] = Jp
    return J


def _normal_equations(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, weight: F64,
    rig: RectifiedStereo, depth_var_px2: F64 | None,
) -> tuple[F64, F64, F64, F64]:
    """Gauss-Newton normal matrix (H, 6, 6), gradient (H, 6), residuals (H, M, 4) and the
    per-feature whitened squared residual (H, M).

    ``depth_var_px2`` (H, M): variance of each point's depth at k-1 (m²) divided by the pixel
    variance. The point is then uncertain along its ray, which adds ``σ_z² a aᵀ`` to its 4x4
    residual covariance (``a`` = residual change per metre of depth); the rank-one inverse
    (Sherman-Morrison) down-weights exactly that direction. Without it far points, whose depth
    is poor, bias the translation scale.
    """
    r, q = reprojection_residuals(R, t, p_prev, uv_left, uv_right, rig)
    J = _jacobian(q, t, rig)
    w = np.where(np.isfinite(r).all(-1), weight, 0.0)
    r = np.where(np.isfinite(r), r, 0.0)
    J = np.where(np.isfinite(J), J, 0.0)
    Jw = (J * w[..., None, None]).reshape(J.shape[0], -1, 6)
    A = np.swapaxes(Jw, 1, 2) @ J.reshape(J.shape[0], -1, 6)
    g = (np.swapaxes(Jw, 1, 2) @ r.reshape(r.shape[0], -1, 1))[..., 0]
    e2 = (r * r).sum(-1)
    if depth_var_px2 is not None:
        ray = (q - t[:, None, :]) / p_prev[..., 2:3]  # R p / z: d(moved point)/d(depth)
        a = np.einsum("hmkj,hmj->hmk", J[..., 3:], np.where(np.isfinite(ray), ray, 0.0))
        s2 = np.where(np.isfinite(depth_var_px2), depth_var_px2, 0.0)
        c = s2 / (1.0 + s2 * (a * a).sum(-1))
        Ja = np.einsum("hmki,hmk->hmi", J, a)
        ar = (a * r).sum(-1)
        wc = w * c
        A = A - np.einsum("hm,hmi,hmj->hij", wc, Ja, Ja)
        g = g - np.einsum("hm,hmi->hi", wc * ar, Ja)
        e2 = e2 - c * ar * ar
    return A, g, r, e2


def gauss_newton(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, weight: F64,
    rig: RectifiedStereo, iterations: int, depth_var_px2: F64 | None = None,
) -> tuple[F64, F64]:
    """Batched Gauss-Newton on eq. 12 for H problems at once.

    ``R`` (H, 3, 3), ``t`` (H, 3) initial motions; ``p_prev`` (H, M, 3) m; ``uv_left``/``uv_right``
    (H, M, 2) px at k; ``weight`` (H, M) in {0, 1} selects features; optional ``depth_var_px2``
    (H, M) models depth uncertainty (see ``_normal_equations``). Returns refined ``R``, ``t``.
    """
    R = R.copy()
    t = t.copy()
    damping = 1e-9 * np.eye(6)
    for _ in range(iterations):
        A, g, _, _ = _normal_equations(R, t, p_prev, uv_left, uv_right, weight, rig, depth_var_px2)
        A = A + damping
        try:
            delta = -np.linalg.solve(A, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = -(np.linalg.pinv(A) @ g[..., None])[..., 0]
        delta = np.where(np.isfinite(delta), delta, 0.0)
        R = so3_exp(delta[:, :3]) @ R
        t = t + delta[:, 3:]
        if np.max(np.abs(delta)) < 1e-9:
            break
    return R, t


def kabsch(p_prev: F64, p_cur: F64) -> tuple[F64, F64]:
    """Batched rigid alignment ``p_cur ≈ R p_prev + t`` of point sets (H, M, 3) -> R (H, 3, 3),
    t (H, 3) (least squares, Umeyama/Kabsch without scale)."""
    mu_a = p_prev.mean(axis=1)
    mu_b = p_cur.mean(axis=1)
    Hm = np.einsum("hmi,hmj->hij", p_cur - mu_b[:, None], p_prev - mu_a[:, None])
    U, _, Vt = np.linalg.svd(Hm)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.broadcast_to(np.eye(3), Hm.shape).copy()
    D[:, 2, 2] = d
    R = U @ D @ Vt
    t = mu_b - np.einsum("hij,hj->hi", R, mu_a)
    return R, t


def _max_error(r: F64) -> F64:
    """Larger of the left and right pixel errors (H, M) from residuals (H, M, 4); NaN -> inf."""
    r2 = r * r
    e2 = np.maximum(r2[..., 0] + r2[..., 1], r2[..., 2] + r2[..., 3])
    return np.sqrt(np.where(np.isfinite(e2), e2, np.inf))


def _covariance(
    R: F64, t: F64, p: F64, uvl: F64, uvr: F64, rig: RectifiedStereo, depth_var_px2: F64 | None
) -> F64:
    """(6, 6) covariance of (local rotation vector, translation) from the normal matrix scaled by
    the residual variance, for one motion and inlier points (M, 3)."""
    dv = None if depth_var_px2 is None else depth_var_px2[None]
    A, _, _, e2 = _normal_equations(
        R[None], t[None], p[None], uvl[None], uvr[None], np.ones((1, p.shape[0])), rig, dv
    )
    dof = max(4 * p.shape[0] - 6, 1)
    sigma2 = float(np.sum(e2)) / dof
    cov_left = sigma2 * np.linalg.pinv(A[0])
    # Left perturbation δθ_l = R δθ_local  =>  Σ_local = R^T Σ_l R.
    Tm = np.eye(6)
    Tm[:3, :3] = R.T
    cov = Tm @ cov_left @ Tm.T
    return 0.5 * (cov + cov.T)


def estimate_egomotion(
    p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo, opts: RansacOptions,
    p_cur: F64 | None = None, prior: Egomotion | None = None,
    rng: np.random.Generator | None = None,
) -> EgomotionResult:
    """RANSAC + Gauss-Newton egomotion from N features.

    ``p_prev`` (N, 3) m in C_{k-1} (NaN rows are never inliers); ``uv_left``/``uv_right`` (N, 2) px
    rectified at k; ``p_cur`` (N, 3) m triangulated at k seeds hypotheses by 3-point alignment;
    ``prior`` (e.g. the previous motion) is one extra hypothesis. Never raises on degenerate input.
    """
    p_prev = np.asarray(p_prev, dtype=float).reshape(-1, 3)
    uv_left = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=float).reshape(-1, 2)
    n = p_prev.shape[0]
    usable = np.isfinite(p_prev).all(1) & (p_prev[:, 2] > _MIN_DEPTH_M)
    usable &= np.isfinite(uv_left).all(1) & np.isfinite(uv_right).all(1)
    if p_cur is not None:
        p_cur = np.asarray(p_cur, dtype=float).reshape(-1, 3)
    nothing = EgomotionResult(None, np.zeros(n, dtype=bool), np.full(n, np.inf))
    idx = np.flatnonzero(usable)
    if idx.size < max(opts.min_inliers, 3):
        return nothing
    rng = rng if rng is not None else np.random.default_rng(opts.seed)
    h = opts.iterations
    triples = idx[np.argsort(rng.random((h, idx.size)), axis=1)[:, :3]]  # (H, 3) distinct
    P3, L3, R3 = p_prev[triples], uv_left[triples], uv_right[triples]
    R0 = np.broadcast_to(np.eye(3), (h, 3, 3)).copy()
    t0 = np.zeros((h, 3))
    if p_cur is not None:
        C3 = p_cur[triples]
        good = np.isfinite(C3).all(axis=(1, 2))
        if good.any():
            try:
                Rk, tk = kabsch(P3[good], C3[good])
                R0[good], t0[good] = Rk, tk
            except np.linalg.LinAlgError:  # degenerate triples: start from identity instead
                pass
    if prior is not None:
        R0 = np.concatenate([R0, prior.R_Ck_Ckm1[None]], axis=0)
        t0 = np.concatenate([t0, prior.p_Ck_Ckm1[None]], axis=0)
        pick = rng.choice(idx, size=3, replace=False)
        P3 = np.concatenate([P3, p_prev[pick][None]])
        L3 = np.concatenate([L3, uv_left[pick][None]])
        R3 = np.concatenate([R3, uv_right[pick][None]])
    Rh, th = gauss_newton(R0, t0, P3, L3, R3, np.ones(P3.shape[:2]), rig, opts.gn_iterations)
    if prior is not None:
        # The prior itself also competes unrefined (it may be better than any triple).
        Rh = np.concatenate([Rh, prior.R_Ck_Ckm1[None]])
        th = np.concatenate([th, prior.p_Ck_Ckm1[None]])
    nh = Rh.shape[0]
    P = np.broadcast_to(p_prev[idx], (nh, idx.size, 3))
    L = np.broadcast_to(uv_left[idx], (nh, idx.size, 2))
    Rr = np.broadcast_to(uv_right[idx], (nh, idx.size, 2))
    err = _max_error(reprojection_residuals(Rh, th, P, L, Rr, rig)[0])
    inl = err < opts.inlier_px
    count = inl.sum(axis=1)
    score = count - np.where(inl, err, 0.0).sum(axis=1) / (opts.inlier_px * (idx.size + 1))
    best = int(np.argmax(score))
    if count[best] < opts.min_inliers:
        return nothing
    R, t = Rh[best : best + 1], th[best : best + 1]
    w = inl[best].astype(float)
    # Depth variance / pixel variance of eq. 10: σ_z = z² σ_d / (f b), σ_d² = 2 σ_px².
    zf = p_prev[idx, 2] ** 2 / (rig.f * rig.baseline)
    dvar = 2.0 * zf * zf if opts.depth_weighting else None
    for _ in range(2):  # refine on inliers, re-select, refine again
        R, t = gauss_newton(
            R, t, p_prev[idx][None], uv_left[idx][None], uv_right[idx][None], w[None], rig,
            opts.refine_iterations, None if dvar is None else dvar[None],
        )
        e = _max_error(reprojection_residuals(R, t, p_prev[idx][None], uv_left[idx][None],
                                              uv_right[idx][None], rig)[0])[0]
        w = (e < opts.inlier_px).astype(float)
    inlier_sub = w > 0
    if inlier_sub.sum() < opts.min_inliers:
        return nothing
    inlier = np.zeros(n, dtype=bool)
    inlier[idx[inlier_sub]] = True
    error = np.full(n, np.inf)
    error[idx] = e
    sel = idx[inlier_sub]
    dsel = None if dvar is None else dvar[inlier_sub]
    cov = _covariance(R[0], t[0], p_prev[sel], uv_left[sel], uv_right[sel], rig, dsel)
    ego = Egomotion(R_Ck_Ckm1=R[0], p_Ck_Ckm1=t[0], cov=cov)
    return EgomotionResult(ego, inlier, error)
