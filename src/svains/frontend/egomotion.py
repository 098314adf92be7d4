"""Stereo egomotion and outlier rejection (paper eqs. 11-12), pure numpy and batched.

Motion ``T_Ck_Ckm1``: ``p_Ck = R p_Ckm1 + t``. A feature triangulated at k-1 (eq. 10) predicts its
left and right pixels at k; Gauss-Newton minimises the stereo reprojection error (eq. 12) over the
six motion parameters. RANSAC fits about 50 random triples *at once* (one batched Gauss-Newton),
keeps the hypothesis with most inliers, and refines on all its inliers.

During Gauss-Newton the rotation is updated on the left, ``R <- Exp(δθ) R``; the reported
covariance is converted to the project's local convention ``R = R̂ Exp(δθ)`` (docs/conventions.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from svains.frontend import egomotion_kernels as kern
from svains.frontend import egomotion_seeds as seeds
from svains.frontend.egomotion_cov import egomotion_covariance
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
    refinement on all inliers, re-selected and refined again for at most ``refine_rounds`` rounds
    until the inlier set stops changing (two rounds left the estimate near the RANSAC
    hypothesis when noise cuts many features: 3x the translation error on 0.5 px features);
    ``min_inliers`` for a motion measurement; ``seed`` of the sampler;
    ``depth_weighting`` models each point's depth uncertainty at k-1 (stereo matching noise equal
    to the pixel noise in each image) in the refinement and the covariance. Hypotheses come in
    two batches: ``first_batch`` triples (plus the prior), and the rest of ``iterations`` only
    if the best inlier ratio ``w`` so far leaves a chance above ``1 - confidence`` that no
    all-inlier triple was drawn (``(1 - w³)^n``): a clean frame then costs a third of the
    hypotheses, a frame with many outliers (a moving object) gets all of them. The default draws
    all 50 at once (the paper's RANSAC): with 16 first, a sharp turn of the 2 Hz village flight
    (frame at t = 35 s, seed 0) ended without consensus and broke stereo VO there.
    With a ``prior`` (the IMU prediction or the last motion), the prior is first refined
    (as the best hypothesis would be) on the features it predicts within ``prior_gate_px``; if
    that keeps at least ``prior_accept_fraction`` of the usable features as inliers it is the
    answer and no triple is drawn (a larger consensus elsewhere cannot exist then). Otherwise
    RANSAC runs as above. On the 20 Hz simulated bench flight 395 of 398 frames take the prior's
    path (RANSAC stage 0.3 ms less per frame), at the 5 Hz of KITTI raw 11 of 178 (a car's
    last motion predicts the next one poorly); above 1 turns it off."""

    iterations: int = 50
    first_batch: int = 50
    prior_gate_px: float = 3.0
    prior_accept_fraction: float = 0.8
    confidence: float = 0.999
    inlier_px: float = 1.5
    gn_iterations: int = 2
    refine_iterations: int = 5
    refine_rounds: int = 10
    refine_tol: float = 1e-6
    min_inliers: int = 8
    seed: int = 0
    depth_weighting: bool = True
    # Covariance of the result (``svains.frontend.egomotion_cov``, all four pixels, the gate
    # above). ``pixel_sigma_px``: white pixel noise, measured on the simulated village images
    # (KLT + stereo KLT, inliers at the true motion: 0.099-0.100 px, seeds 0-1, 2 Hz,
    # bench/eval_frontend_sim.py). ``cov_robust``: a larger white noise seen in the residuals
    # (features0 at 0.5 px) takes over. ``cov_inflation``: floor on the effective pixel variance,
    # in units of pixel_sigma_px²: the image front end's errors are shared across features (a
    # per-frame scale error of ~0.9 %, the motion pulled toward its prediction), so they do not
    # average down. Fitted on seeds 0-1 (1.0 gives NEES 80); 13 gives a mean NEES of 6.2-6.7
    # on seeds 0-3, with and without the moving object (30 s each).
    pixel_sigma_px: float = 0.1
    cov_robust: bool = True
    cov_inflation: float = 13.0


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


def gauss_newton(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, weight: F64,
    rig: RectifiedStereo, iterations: int, depth_var_px2: F64 | None = None, tol: float = 1e-9,
) -> tuple[F64, F64]:
    """Batched Gauss-Newton on eq. 12 for H problems at once (compiled loop,
    ``egomotion_kernels.gauss_newton_batch``).

    ``R`` (H, 3, 3), ``t`` (H, 3) initial motions; ``p_prev`` (H, M, 3) m; ``uv_left``/``uv_right``
    (H, M, 2) px at k; ``weight`` (H, M) in {0, 1} selects features; each problem stops once its
    update is below ``tol`` (rad, m). Returns refined ``R``, ``t``.

    ``depth_var_px2`` (H, M): variance of each point's depth at k-1 (m²) divided by the pixel
    variance. The point is then uncertain along its ray, which adds ``σ_z² a aᵀ`` to its 4x4
    residual covariance (``a`` = residual change per metre of depth); the rank-one inverse
    (Sherman-Morrison) down-weights exactly that direction. Without it far points, whose depth
    is poor, bias the translation scale. Points behind the camera get no weight.
    """
    R = np.array(R, dtype=float, order="C")
    t = np.array(t, dtype=float, order="C")
    c = np.ascontiguousarray
    use_dv = depth_var_px2 is not None
    dv = c(depth_var_px2, dtype=float) if use_dv else np.zeros(np.shape(weight))
    kern.gauss_newton_batch(
        R, t, c(p_prev, dtype=float), c(uv_left, dtype=float), c(uv_right, dtype=float),
        c(weight, dtype=float), dv, use_dv, rig.f, rig.cu, rig.cv, rig.baseline, int(iterations),
        float(tol),
    )
    return R, t


def kabsch(p_prev: F64, p_cur: F64) -> tuple[F64, F64]:
    """Batched rigid alignment ``p_cur ≈ R p_prev + t`` of point sets (H, M, 3) -> R (H, 3, 3),
    t (H, 3) (least squares without scale; compiled, ``egomotion_kernels.align_batch``). A set
    with a non-finite point gets the identity."""
    P = np.ascontiguousarray(p_prev, dtype=float)
    C = np.ascontiguousarray(p_cur, dtype=float)
    R = np.empty((P.shape[0], 3, 3))
    t = np.empty((P.shape[0], 3))
    seeds.align_batch(P, C, R, t)
    return R, t


def _score(
    R: F64, t: F64, p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo,
    inlier_px: float,
) -> tuple[F64, Bool]:
    """RANSAC score (H,) and inlier masks (H, M) of motions ``R`` (H, 3, 3), ``t`` (H, 3) on
    shared features ``p_prev`` (M, 3), pixels (M, 2): the inlier count minus a small penalty
    growing with the inliers' errors (ties go to the tighter fit); a point behind the camera is
    never an inlier (compiled loop, ``egomotion_kernels.score_batch``)."""
    c = np.ascontiguousarray
    return kern.score_batch(
        c(R, dtype=float), c(t, dtype=float), c(p_prev, dtype=float), c(uv_left, dtype=float),
        c(uv_right, dtype=float), rig.f, rig.cu, rig.cv, rig.baseline, float(inlier_px),
    )


def _distinct_triples(rng: np.random.Generator, h: int, n: int) -> NDArray[np.int64]:
    """``h`` rows of 3 distinct indices in [0, n), uniform over unordered triples: draws from
    [0, n), [0, n-1), [0, n-2) shifted past the indices already taken (no per-row loop, no
    (h, n) random keys)."""
    a, b, c = (rng.integers(0, n - k, h) for k in range(3))
    b = b + (b >= a)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = c + (c >= lo)
    c = c + (c >= hi)
    return np.stack([a, b, c], axis=1)


def _hypotheses(
    h: int, idx: NDArray[np.int64], p_prev: F64, uv_left: F64, uv_right: F64, p_cur: F64 | None,
    prior: Egomotion | None, rig: RectifiedStereo, opts: RansacOptions, rng: np.random.Generator,
) -> tuple[F64, F64]:
    """``h`` motions (R (H', 3, 3), t (H', 3)) fitted to random triples of the usable features
    ``idx``, seeded by 3-point alignment of ``p_cur``; with a ``prior`` it is refined on one more
    triple and also competes unrefined (H' = h + 2)."""
    triples = idx[_distinct_triples(rng, h, idx.size)]  # (H, 3)
    R_p, t_p = np.eye(3), np.zeros(3)
    if prior is not None:
        R_p, t_p = prior.R_Ck_Ckm1, prior.p_Ck_Ckm1
        triples = np.concatenate([triples, rng.choice(idx, size=3, replace=False)[None]])
    n_out = triples.shape[0] + (prior is not None)
    Rh, th = np.empty((n_out, 3, 3)), np.empty((n_out, 3))
    # Triples with a non-finite point at k start from the identity (compiled: one call).
    c = np.ascontiguousarray
    seeds.triple_hypotheses(
        p_prev, uv_left, uv_right, p_prev if p_cur is None else p_cur, p_cur is not None,
        triples, c(R_p, dtype=float), c(t_p, dtype=float), prior is not None,
        opts.gn_iterations, rig.f, rig.cu, rig.cv, rig.baseline, Rh, th,
    )
    return Rh, th


def _from_prior(
    prior: Egomotion, P_i: F64, L_i: F64, R_i: F64, rig: RectifiedStereo, opts: RansacOptions,
    refine: Callable[[F64, F64, F64], None], e: F64,
) -> tuple[F64, F64, F64] | None:
    """The prior refined on the features it predicts within ``prior_gate_px`` (``refine``
    re-selects them at ``inlier_px``), if that keeps ``prior_accept_fraction`` of them:
    R (3, 3), t (3,), selection (M,) in {0, 1}; else None. ``e`` (M,) px: scratch errors."""
    need = max(opts.min_inliers, opts.prior_accept_fraction * P_i.shape[0])
    if opts.prior_accept_fraction > 1.0 or P_i.shape[0] < need:
        return None
    R = np.array(prior.R_Ck_Ckm1, dtype=float, order="C")
    t = np.array(prior.p_Ck_Ckm1, dtype=float, order="C")
    kern.max_errors(R, t, P_i, L_i, R_i, rig.f, rig.cu, rig.cv, rig.baseline, e)
    w = (e < opts.prior_gate_px).astype(float)
    if w.sum() < need:
        return None
    refine(R, t, w)
    return (R, t, w) if w.sum() >= need else None


def _ransac(
    idx: NDArray[np.int64], p_prev: F64, uv_left: F64, uv_right: F64, p_cur: F64 | None,
    prior: Egomotion | None, rig: RectifiedStereo, opts: RansacOptions, rng: np.random.Generator,
    sub: tuple[F64, F64, F64],
) -> tuple[F64, F64, F64] | None:
    """RANSAC over random triples of the usable features ``idx`` (and the prior): the best
    hypothesis R (3, 3), t (3,) and its inliers (M,) in {0, 1} among ``idx``; None if it has
    fewer than ``min_inliers``. ``sub``: points and pixels of the features ``idx``."""
    h1 = min(opts.iterations, max(opts.first_batch, 1))
    Rh, th = _hypotheses(h1, idx, p_prev, uv_left, uv_right, p_cur, prior, rig, opts, rng)
    P_i, L_i, R_i = sub
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
        return None
    return Rh[best].copy(), th[best].copy(), inl[best].astype(float)


def estimate_egomotion(
    p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo, opts: RansacOptions,
    p_cur: F64 | Callable[[], F64] | None = None, prior: Egomotion | None = None,
    rng: np.random.Generator | None = None, covariance: bool = True,
) -> EgomotionResult:
    """RANSAC + Gauss-Newton egomotion from N features.

    ``p_prev`` (N, 3) m in C_{k-1} (NaN rows are never inliers); ``uv_left``/``uv_right`` (N, 2) px
    rectified at k; ``p_cur`` (N, 3) m triangulated at k seeds hypotheses by 3-point alignment
    (or a function giving them, called only if random hypotheses are drawn);
    ``prior`` (e.g. the previous motion) is one extra hypothesis. Never raises on degenerate input.
    ``covariance`` False: the motion only, its ``cov`` NaN (``egomotion_covariance`` is about
    half the cost; the motion and inliers are the same either way).
    """
    p_prev = np.asarray(p_prev, dtype=float).reshape(-1, 3)
    uv_left = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=float).reshape(-1, 2)
    n = p_prev.shape[0]
    usable = np.isfinite(p_prev).all(1) & (p_prev[:, 2] > _MIN_DEPTH_M)
    usable &= np.isfinite(uv_left).all(1) & np.isfinite(uv_right).all(1)
    nothing = EgomotionResult(None, np.zeros(n, dtype=bool), np.full(n, np.inf))
    idx = np.flatnonzero(usable)
    if idx.size < max(opts.min_inliers, 3):
        return nothing
    P_i, L_i, R_i = p_prev[idx], uv_left[idx], uv_right[idx]
    # Depth variance / pixel variance of eq. 10: σ_z = z² σ_d / (f b), σ_d² = 2 σ_px².
    zf = P_i[:, 2] ** 2 / (rig.f * rig.baseline)
    dvar = 2.0 * zf * zf if opts.depth_weighting else None
    e = np.empty(idx.size)

    def refine(R: F64, t: F64, w: F64) -> None:
        """Refine, re-select, until the set settles (compiled: one call for all rounds)."""
        kern.refine_select(
            R, t, P_i, L_i, R_i, w, zf if dvar is None else dvar, dvar is not None, rig.f,
            rig.cu, rig.cv, rig.baseline, opts.refine_iterations, float(opts.refine_tol),
            opts.refine_rounds, float(opts.inlier_px), e,
        )

    got = None if prior is None else _from_prior(prior, P_i, L_i, R_i, rig, opts, refine, e)
    if got is None:
        rng = rng if rng is not None else np.random.default_rng(opts.seed)
        if callable(p_cur):
            p_cur = p_cur()
        if p_cur is not None:
            p_cur = np.ascontiguousarray(p_cur, dtype=float).reshape(-1, 3)
        got = _ransac(idx, p_prev, uv_left, uv_right, p_cur, prior, rig, opts, rng,
                      (P_i, L_i, R_i))  # fmt: skip
        if got is None:
            return nothing
        refine(*got)
    R, t, w = got
    inlier_sub = w > 0
    if inlier_sub.sum() < opts.min_inliers:
        return nothing
    inlier = np.zeros(n, dtype=bool)
    inlier[idx[inlier_sub]] = True
    error = np.full(n, np.inf)
    error[idx] = e
    if not covariance:
        return EgomotionResult(Egomotion(R_Ck_Ckm1=R, p_Ck_Ckm1=t, cov=np.full((6, 6), np.nan)),
                               inlier, error)  # fmt: skip
    sel = idx[inlier_sub]
    dsel = None if dvar is None else dvar[inlier_sub]
    cov = egomotion_covariance(
        R, t, p_prev[sel], uv_left[sel], uv_right[sel], rig, opts.pixel_sigma_px,
        robust=opts.cov_robust, inflation=opts.cov_inflation, estimator_depth_var_px2=dsel,
        gate_px=opts.inlier_px,
    )
    ego = Egomotion(R_Ck_Ckm1=R, p_Ck_Ckm1=t, cov=cov)
    return EgomotionResult(ego, inlier, error)


# The inlier thresholds (px) of the retries of ``estimate_egomotion_widening`` when the options'
# own (1.5 px, made for frames 50-200 ms apart) finds no motion. RANSAC takes the k-1 points as
# exact; across a baseline of metres their depth noise alone reprojects the true motion to
# several pixels, and to tens once the view turns: EuRoC V1_01 with 0.5 px features, a frame
# 6.75 s after the previous one (2.0 m, 118 deg, 17 shared features at 1.7-3.1 m) puts the
# true motion at 1.2-34 px, so 1.5 and 5 px find no consensus and 10 / 20 px find it within
# 2.6 / 1.2 cm. A retry's motion counts only when its inliers are a majority of the usable
# features (``WIDENING_MIN_INLIER_FRACTION``): the same data, a frame 4.6 s after the previous
# one, has a 5 px consensus of 8 of 57 features that is 1.09 m and 10.5 deg wrong, while 32 of
# the 57 agree within 20 px on a motion 4 cm from the truth.
WIDENING_INLIER_PX = (5.0, 10.0, 20.0)
WIDENING_MIN_INLIER_FRACTION = 0.5


def estimate_egomotion_widening(
    p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo, opts: RansacOptions,
    p_cur: F64 | Callable[[], F64] | None = None, prior: Egomotion | None = None,
    rng: np.random.Generator | None = None,
    wider_px: tuple[float, ...] = WIDENING_INLIER_PX,
    min_fraction: float = WIDENING_MIN_INLIER_FRACTION, covariance: bool = True,
) -> EgomotionResult:
    """``estimate_egomotion`` at ``opts.inlier_px``; while that finds no motion, again at each
    of ``wider_px`` above it (same seed; arguments as there), where a motion counts only if at
    least ``min_fraction`` of the usable features (finite k-1 point) are its inliers. For
    frames far apart, whose k-1 depth noise moves even the true motion's reprojections by more
    than the threshold. Returns the first motion that counts, else the first try's result."""
    first = estimate_egomotion(p_prev, uv_left, uv_right, rig, opts, p_cur, prior, rng,
                               covariance)  # fmt: skip
    if first.egomotion is not None:
        return first
    usable = int(np.isfinite(np.asarray(p_prev, float).reshape(-1, 3)).all(axis=1).sum())
    if callable(p_cur):  # triangulated once for every retry
        p_cur = p_cur()
    for px in wider_px:
        if px <= opts.inlier_px:
            continue
        res = estimate_egomotion(p_prev, uv_left, uv_right, rig, replace(opts, inlier_px=px),
                                 p_cur, prior, rng, covariance)  # fmt: skip
        if res.egomotion is not None and res.inlier.sum() >= min_fraction * usable:
            return res
    return first


_warm = False


def warm_up(rig: RectifiedStereo) -> None:
    """Run ``estimate_egomotion`` once on a small exact problem, with and without a prior, so
    that the compiled kernels are loaded now (numba's first call in a process costs ~0.3 s of
    start-up, then 5-20 ms per kernel): at set-up instead of on the first frame, which would
    otherwise stall that long. Once per process."""
    global _warm
    if _warm:
        return
    rng = np.random.default_rng(0)
    z = rng.uniform(2.0, 20.0, 24)
    uv = np.c_[rng.uniform(0, rig.width - 1, 24), rng.uniform(0, rig.height - 1, 24)]
    p = np.c_[(uv[:, 0] - rig.cu) * z / rig.f, (uv[:, 1] - rig.cv) * z / rig.f, z]
    uvl, uvr = rig.project(p), rig.project_right(p)
    still = Egomotion(R_Ck_Ckm1=np.eye(3), p_Ck_Ckm1=np.zeros(3), cov=np.eye(6))
    for prior in (still, None):
        estimate_egomotion(p, uvl, uvr, rig, RansacOptions(iterations=4, first_batch=4),
                           p_cur=p, prior=prior, rng=rng)  # fmt: skip
    _warm = True
