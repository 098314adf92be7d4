"""Two-frame stereo bundle adjustment: the egomotion and every feature's point, fitted jointly
to all four pixels of each feature (left and right at k-1 and at k).

Why: the RANSAC estimate (``egomotion.estimate_egomotion``) takes the points triangulated at k-1
as given and keeps the features whose k pixels it predicts within 1.5 px. With 0.5 px noise
that gate cuts ~40 % of the features, and which ones it cuts depends on their k-1 noise: the
survivors' errors lean one way and the estimate is biased the same way every frame (on the
village at 5 Hz, pan -0.18 mrad and 3.6 mm sideways per frame, 18 and 20 standard errors), so
summed egomotions drift faster than their covariance says. The joint fit weighs every pixel
once, the k-1 pixels included, and gates each feature on its own joint residual, so it keeps
the features the noise alone explains (figures in ``BundleOptions``; tests in
``tests/test_frontend_egomotion_bundle.py``).

Model (conventions in docs/conventions.md): motion ``T_Ck_Ckm1``, ``p_Ck = R p_Ckm1 + t``; the
rotation error is local, ``R = R̂ Exp(δθ)``. Feature i is an inverse-depth point anchored in the
left camera at k-1: ``p_Ckm1 = (α, β, 1) / ρ`` (ρ in 1/m; a point at infinity is ρ = 0 and stays
well conditioned). Its pixels, rectified, baseline ``b`` along the left camera's +x:

    k-1: u_l = f α + c_u,  v_l = f β + c_v,  u_r = f (α - b ρ) + c_u,  v_r = v_l
    k:   h = R (α, β, 1) + ρ t;  u_l = f h_x / h_z + c_u,  v_l = f h_y / h_z + c_v,
         u_r = f (h_x - b ρ) / h_z + c_u,  v_r = v_l

Gauss-Newton on the 6 + 3M unknowns, the points eliminated per feature (Schur complement on
their 3x3 blocks, vectorised over features). The covariance is ``σ² S⁻¹`` with ``S`` the reduced
6x6 information and ``σ²`` the pixel variance estimated from the inliers' residuals (5 degrees
of freedom per feature: 8 pixels, 3 point coordinates), floored at ``BundleOptions.min_sigma_px``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.frontend import egomotion_bundle_kernels as kern
from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]

log = logging.getLogger(__name__)

_DOF = 5  # per feature: 8 pixel residuals minus 3 point coordinates
_CHI2_MEDIAN = float(chi2.ppf(0.5, _DOF))


@dataclass(frozen=True)
class BundleOptions:
    """Two-frame bundle adjustment settings: at most ``iterations`` Gauss-Newton steps per
    round, stopping once the motion update's squared Mahalanobis length ``δxᵀ S δx / σ²`` is
    below ``step_tol`` (1e-4: a step of 1 % of a standard deviation); ``rounds`` of re-selecting
    the inliers (each feature's point refined for the current motion, its squared residual in
    units of σ² against the chi-square quantile ``gate_probability`` with 5 degrees of freedom)
    until the set repeats; ``min_sigma_px`` floors the pixel noise estimated from the residuals
    (the image front end's KLT noise, 0.1 px, ``RansacOptions.pixel_sigma_px``); fewer than
    ``min_features`` inliers give no motion.

    Measured on features0 (0.5 px, true landmark projections; errors of each frame's estimate
    against the true motion; forward = the RANSAC estimate with its own covariance):

    ==========================  ===============  ==================  ========================
    flight                      NEES (6 dof)     NEES of 10 summed   rms pan [mrad] / side
                                fwd / bundle     fwd / bundle        [mm], fwd / bundle
    ==========================  ===============  ==================  ========================
    village 60 s, 5 Hz          5.01 / 5.84      18.2 / 2.82         0.247 / 0.077, 4.66/1.06
    V1_02 trajectory, 2 Hz      3.66 / 6.21      5.69 / 4.73         1.90 / 0.29, 35.8 / 3.52
    MH_03 trajectory, 2 Hz      5.53 / 6.36      3.60 / 5.69         3.85 / 0.60, 59.8 / 5.68
    V1_02 trajectory, 0.5 Hz    18.5 / 8.19      4.23 / 4.97         24.2 / 1.86, 647 / 21.2
    ==========================  ===============  ==================  ========================
    """

    iterations: int = 8
    rounds: int = 5
    step_tol: float = 1e-4
    gate_probability: float = 0.999
    min_sigma_px: float = 0.1
    min_features: int = 8


@dataclass(frozen=True)
class BundleResult:
    """``egomotion`` (None when the fit failed), ``inlier`` (N,) over the input features,
    ``sigma_px`` the pixel noise the covariance uses, ``rounds`` of inlier selection run."""

    egomotion: Egomotion | None
    inlier: Bool
    sigma_px: float
    rounds: int


def refine_two_frame(
    R_Ck_Ckm1: F64, p_Ck_Ckm1: F64, uv_left_prev: F64, uv_right_prev: F64, uv_left: F64,
    uv_right: F64, rig: RectifiedStereo, inlier: Bool, options: BundleOptions | None = None,
    candidate: Bool | None = None,
) -> BundleResult:
    """The egomotion ``T_Ck_Ckm1`` fitted jointly with the features' points to their four pixels.

    ``R_Ck_Ckm1`` (3, 3), ``p_Ck_Ckm1`` (3,) m: the starting motion (the RANSAC estimate);
    ``uv_*_prev`` (N, 2) rectified px at k-1, ``uv_*`` (N, 2) at k; ``inlier`` (N,) the starting
    inlier set (RANSAC's); ``candidate`` (N,) the features that may be inliers (None: all).
    Features with non-finite pixels or no positive disparity at k-1 are never inliers. Never
    raises on degenerate input: the result's ``egomotion`` is then None.
    """
    o = options or BundleOptions()
    n = len(inlier)
    z_prev = np.ascontiguousarray(np.concatenate([uv_left_prev, uv_right_prev], axis=1), float)
    z_cur = np.ascontiguousarray(np.concatenate([uv_left, uv_right], axis=1), float)
    usable = np.isfinite(z_prev).all(1) & np.isfinite(z_cur).all(1)
    usable &= z_prev[:, 0] - z_prev[:, 2] > 0
    if candidate is not None:
        usable &= np.asarray(candidate, dtype=bool)
    act = np.asarray(inlier, dtype=bool) & usable
    nothing = BundleResult(None, np.zeros(n, dtype=bool), float("nan"), 0)
    if act.sum() < o.min_features:
        return nothing
    f, b, cu, cv = rig.f, rig.baseline, rig.cu, rig.cv
    # Inverse-depth points from the k-1 pixels (eq. 10: ρ = d / (f b)).
    a = np.empty((n, 3))
    a[:, 0] = (z_prev[:, 0] - cu) / f
    a[:, 1] = (z_prev[:, 1] - cv) / f
    a[:, 2] = (z_prev[:, 0] - z_prev[:, 2]) / (f * b)
    a[~usable] = 0.0
    R = np.array(R_Ck_Ckm1, dtype=float, order="C")
    t = np.array(p_Ck_Ckm1, dtype=float)
    gate = float(chi2.ppf(o.gate_probability, _DOF))
    S, s = np.empty((6, 6)), np.empty(6)
    e2 = np.empty(n)
    sigma2 = o.min_sigma_px**2
    rounds = 0
    while rounds < o.rounds:
        rounds += 1
        sel = np.flatnonzero(act)
        Hi, Hpx, gp = _blocks(sel.size)
        for _ in range(o.iterations):
            if kern.reduced_system(R, t, a, z_prev, z_cur, sel, f, b, cu, cv, S, s, Hi, Hpx,
                                   gp) < 0:  # fmt: skip
                return nothing
            dx = _solve6(S, s)
            if dx is None:
                return nothing
            R = np.ascontiguousarray(R @ so3_exp(dx[:3]))
            t = t + dx[3:]
            kern.back_substitute(a, sel, dx, Hi, Hpx, gp)
            # Below 1 % of a standard deviation (with noise Gauss-Newton converges linearly
            # here, at ~0.2 per step: a fixed 1e-8 rad/m took 8 steps every round).
            if float(dx @ S @ dx) < o.step_tol * sigma2:
                break
        kern.refine_points(R, t, a, z_prev, z_cur, f, b, cu, cv, 3, e2)
        e2[~usable] = np.inf
        # Robust: the median of the inliers' chi-square with 5 degrees of freedom.
        sigma2 = max(float(np.median(e2[act])) / _CHI2_MEDIAN, o.min_sigma_px**2)
        if not np.isfinite(sigma2):
            return nothing
        new = e2 <= gate * sigma2
        if new.sum() < o.min_features:
            return nothing
        if np.array_equal(new, act):
            break
        act = new
    sel = np.flatnonzero(act)
    Hi, Hpx, gp = _blocks(sel.size)
    cost = kern.reduced_system(R, t, a, z_prev, z_cur, sel, f, b, cu, cv, S, s, Hi, Hpx, gp)
    if cost < 0:
        return nothing
    # The inliers' own spread, unbiased for the 5 degrees of freedom per feature and the 6 of
    # the motion (the gate at 0.999 hardly truncates it).
    sigma2 = max(cost / (_DOF * sel.size - 6), o.min_sigma_px**2)
    try:
        cov = sigma2 * np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return nothing
    cov = 0.5 * (cov + cov.T)
    if not (np.isfinite(cov).all() and np.isfinite(R).all() and np.isfinite(t).all()):
        return nothing
    ego = Egomotion(R_Ck_Ckm1=R, p_Ck_Ckm1=t, cov=cov, estimator="bundle")
    return BundleResult(ego, act.copy(), float(np.sqrt(sigma2)), rounds)


def refine_or_keep(
    ego: Egomotion, inlier: Bool, uv_left_prev: F64, uv_right_prev: F64, uv_left: F64,
    uv_right: F64, rig: RectifiedStereo, candidate: Bool | None = None,
) -> tuple[Egomotion, Bool]:
    """``ego`` (RANSAC's) and its ``inlier`` mask (N,) refined by ``refine_two_frame`` on the
    ``candidate`` features (None: all); both unchanged when the refinement fails."""
    res = refine_two_frame(ego.R_Ck_Ckm1, ego.p_Ck_Ckm1, uv_left_prev, uv_right_prev, uv_left,
                           uv_right, rig, inlier, candidate=candidate)  # fmt: skip
    if res.egomotion is None:
        log.debug("two-frame bundle adjustment failed; the RANSAC egomotion is kept")
        return ego, inlier
    return res.egomotion, res.inlier


def _blocks(m: int) -> tuple[F64, F64, F64]:
    """Work arrays of ``kern.reduced_system`` for ``m`` features."""
    return np.empty((m, 3, 3)), np.empty((m, 3, 6)), np.empty((m, 3))


def _solve6(S: F64, s: F64) -> F64 | None:
    """``δx`` with ``S δx = -s``; None when ``S`` is singular or the step not finite."""
    try:
        dx = -np.linalg.solve(S, s)
    except np.linalg.LinAlgError:
        return None
    return dx if np.isfinite(dx).all() else None
