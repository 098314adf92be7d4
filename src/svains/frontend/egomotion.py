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

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]

_MIN_DEPTH_M = 1e-3


@dataclass(frozen=True)
class RansacOptions:
    """RANSAC/Gauss-Newton settings: ``iterations`` random triples; ``inlier_px`` limit on the
    larger of the left and right reprojection errors; ``gn_iterations`` per hypothesis,
    ``refine_iterations`` (at most, stopping once updates fall below ``refine_tol`` rad/m) for the
    refinement on all inliers; ``min_inliers`` for a motion measurement; ``seed`` of the sampler;
    ``depth_weighting`` models each point's depth uncertainty at k-1 (stereo matching noise equal
    to the pixel noise in each image) in the refinement and the covariance. Hypotheses come in
    two batches: ``first_batch`` triples (plus the prior), and the rest of ``iterations`` only
    if the best inlier ratio ``w`` so far leaves a chance above ``1 - confidence`` that no
    all-inlier triple was drawn (``(1 - w³)^n``): a clean frame then costs a third of the
    hypotheses, a frame with many outliers (a moving object) gets all of them. The default draws
    all 50 at once (the paper's RANSAC): with 16 first, a sharp turn of the 2 Hz village flight
    (frame at t = 35 s, seed 0) ended without consensus and broke stereo VO there."""

    iterations: int = 50
    first_batch: int = 50
    confidence: float = 0.999
    inlier_px: float = 1.5
    gn_iterations: int = 2
    refine_iterations: int = 5
    refine_tol: float = 1e-6
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
    points (H, M, 3) for motions ``R`` (H, 3, 3), ``t`` (H, 3) and points ``p_prev`` (H, M, 3),
    or (M, 3) with pixels (M, 2) shared by every motion (then one matrix product moves them all).
    """
    h = R.shape[0]
    if p_prev.ndim == 2:
        # (M, 3) @ (3, 3H): all hypotheses in one BLAS call instead of H tiny ones.
        m = p_prev.shape[0]
        q = (p_prev @ R.transpose(2, 0, 1).reshape(3, 3 * h)).reshape(m, h, 3).transpose(1, 0, 2)
        q = q + t[:, None, :]
    else:
        q = p_prev @ np.swapaxes(R, 1, 2) + t[:, None, :]
    z = q[..., 2]
    iz = rig.f / np.where(z > _MIN_DEPTH_M, z, np.nan)
    vl = q[..., 1] * iz + rig.cv
    ul = q[..., 0] * iz + rig.cu
    r = np.empty((*q.shape[:-1], 4))
    r[..., 0] = ul - uv_left[..., 0]
    r[..., 1] = vl - uv_left[..., 1]
    r[..., 2] = ul - rig.baseline * iz - uv_right[..., 0]
    r[..., 3] = vl - uv_right[..., 1]
    return r, q


def _jacobian(q: F64, t: F64, rig: RectifiedStereo) -> F64:
    """d residual / d (δθ, δt), (H, M, 4, 6), at moved points ``q`` (H, M, 3)."""
    x, y = q[..., 0], q[..., 1]
    z = np.where(q[..., 2] > _MIN_DEPTH_M, q[..., 2], np.nan)
    fz = rig.f / z
    # Projection Jacobian rows d(u, v)/dq: left u = (fz, 0, c0), left v = right v = (0, fz, c1),
    # right u = (fz, 0, c2) (right camera: x - b).
    c0 = -fz * x / z
    c1 = -fz * y / z
    c2 = -fz * (x - rig.baseline) / z
    # q = Exp(δθ) R p + t + δt: dq/dδθ = -[R p]x, so each row a maps to (R p) x a; dq/dδt = I.
    # The cross products are written out (np.cross on tiny trailing axes is slow).
    px, py, pz = (q[..., i] - t[:, None, i] for i in range(3))
    J = np.zeros((*q.shape[:-1], 4, 6))
    J[..., 0, 0] = py * c0
    J[..., 0, 1] = pz * fz - px * c0
    J[..., 0, 2] = -py * fz
    J[..., 0, 3] = fz
    J[..., 0, 5] = c0
    J[..., 1, 0] = py * c1 - pz * fz
    J[..., 1, 1] = -px * c1
    J[..., 1, 2] = px * fz
    J[..., 1, 4] = fz
    J[..., 1, 5] = c1
    J[..., 2, 0] = py * c2
    J[..., 2, 1] = J[..., 0, 1] - px * (c2 - c0)
    J[..., 2, 2] = J[..., 0, 2]
    J[..., 2, 3] = fz
    J[..., 2, 5] = c2
    J[..., 3, :] = J[..., 1, :]
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
    w = weight
    if not np.isfinite(r).all():  # points behind the camera: no say in the fit
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
        A = A - np.swapaxes(Ja * wc[..., None], 1, 2) @ Ja
        g = g - ((wc * ar)[:, None, :] @ Ja)[:, 0]
        e2 = e2 - c * ar * ar
    return A, g, r, e2


def _rodrigues(w: F64) -> F64:
    """``Exp`` of rotation vectors (H, 3) -> (H, 3, 3), written out for the small batched
    updates of Gauss-Newton (series coefficients below 1e-4 rad)."""
    th2 = np.einsum("hi,hi->h", w, w)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def gauss_newton(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, weight: F64,
    rig: RectifiedStereo, iterations: int, depth_var_px2: F64 | None = None, tol: float = 1e-9,
) -> tuple[F64, F64]:
    """Batched Gauss-Newton on eq. 12 for H problems at once.

    ``R`` (H, 3, 3), ``t`` (H, 3) initial motions; ``p_prev`` (H, M, 3) m; ``uv_left``/``uv_right``
    (H, M, 2) px at k; ``weight`` (H, M) in {0, 1} selects features; optional ``depth_var_px2``
    (H, M) models depth uncertainty (see ``_normal_equations``); stops early once every update is
    below ``tol`` (rad, m). Returns refined ``R``, ``t``.
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
        R = _rodrigues(delta[:, :3]) @ R
        t = t + delta[:, 3:]
        if np.max(np.abs(delta)) < tol:
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


def _score(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo,
    inlier_px: float,
) -> tuple[F64, Bool]:
    """RANSAC score (H,) and inlier masks (H, M) of motions ``R`` (H, 3, 3), ``t`` (H, 3) on
    shared features ``p_prev`` (M, 3), pixels (M, 2): the inlier count minus a small penalty
    growing with the inliers' errors (ties go to the tighter fit). Squared errors avoid a
    square root per hypothesis and feature; a point behind the camera is never an inlier."""
    h, m = R.shape[0], p_prev.shape[0]
    q = (p_prev @ R.transpose(2, 0, 1).reshape(3, 3 * h)).reshape(m, h, 3)
    q += t[None]
    z = q[..., 2]
    iz = rig.f / np.where(z > _MIN_DEPTH_M, z, np.nan)
    du = q[..., 0] * iz + (rig.cu - uv_left[:, None, 0])
    dv = q[..., 1] * iz + rig.cv
    dur = du - rig.baseline * iz + (uv_left[:, None, 0] - uv_right[:, None, 0])
    dvl = dv - uv_left[:, None, 1]
    dvr = dv - uv_right[:, None, 1]
    e2 = np.maximum(du * du + dvl * dvl, dur * dur + dvr * dvr).T  # (H, M), NaN behind camera
    inl = e2 < inlier_px * inlier_px
    err_sum = np.sqrt(np.where(inl, e2, 0.0)).sum(axis=1)
    score = inl.sum(axis=1) - err_sum / (inlier_px * (m + 1))
    return score, inl


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


def _hypotheses(
    h: int, idx: NDArray[np.int64], p_prev: F64, uv_left: F64, uv_right: F64, p_cur: F64 | None,
    prior: Egomotion | None, rig: RectifiedStereo, opts: RansacOptions, rng: np.random.Generator,
) -> tuple[F64, F64]:
    """``h`` motions (R (H', 3, 3), t (H', 3)) fitted to random triples of the usable features
    ``idx``, seeded by 3-point alignment of ``p_cur``; with a ``prior`` it is refined on one more
    triple and also competes unrefined (H' = h + 2)."""
    # Three distinct features per hypothesis: the 3 smallest of a random key per feature.
    triples = idx[np.argpartition(rng.random((h, idx.size)), 2, axis=1)[:, :3]]  # (H, 3)
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
    return Rh, th


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
    h1 = min(opts.iterations, max(opts.first_batch, 1))
    Rh, th = _hypotheses(h1, idx, p_prev, uv_left, uv_right, p_cur, prior, rig, opts, rng)
    P_i, L_i, R_i = p_prev[idx], uv_left[idx], uv_right[idx]
    score, inl = _score(Rh, th, P_i, L_i, R_i, rig, opts.inlier_px)
    h2 = opts.iterations - h1
    if h2 > 0:
        w3 = (inl.sum(axis=1).max() / idx.size) ** 3
        # Chance that none of the h1 triples was all inliers, at the best ratio found so far.
        miss = (1.0 - w3) ** h1 if w3 < 1.0 else 0.0
        if miss > 1.0 - opts.confidence:
            R2, t2 = _hypotheses(h2, idx, p_prev, uv_left, uv_right, p_cur, None, rig, opts, rng)
            s2, i2 = _score(R2, t2, P_i, L_i, R_i, rig, opts.inlier_px)
            Rh, th = np.concatenate([Rh, R2]), np.concatenate([th, t2])
            score, inl = np.concatenate([score, s2]), np.concatenate([inl, i2])
    best = int(np.argmax(score))
    if inl[best].sum() < opts.min_inliers:
        return nothing
    R, t = Rh[best : best + 1], th[best : best + 1]
    w = inl[best].astype(float)
    # Depth variance / pixel variance of eq. 10: σ_z = z² σ_d / (f b), σ_d² = 2 σ_px².
    zf = p_prev[idx, 2] ** 2 / (rig.f * rig.baseline)
    dvar = 2.0 * zf * zf if opts.depth_weighting else None
    P1, L1, R1 = p_prev[idx][None], uv_left[idx][None], uv_right[idx][None]
    for _ in range(2):  # refine on inliers, re-select, refine again (if the selection changed)
        R, t = gauss_newton(
            R, t, P1, L1, R1, w[None], rig, opts.refine_iterations,
            None if dvar is None else dvar[None], tol=opts.refine_tol,
        )
        e = _max_error(reprojection_residuals(R, t, P1, L1, R1, rig)[0])[0]
        w_new = (e < opts.inlier_px).astype(float)
        same = bool(np.array_equal(w_new, w))
        w = w_new
        if same:
            break
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
