"""Egomotion covariance from all four pixels: Monte Carlo consistency on exact stereo geometry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from svains.frontend.egomotion import RansacOptions, estimate_egomotion
from svains.frontend.egomotion_cov import egomotion_covariance, whitened_residuals
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp, so3_log

RIG = RectifiedStereo(458.654, 367.215, 248.375, 0.11, np.eye(3), np.zeros(3), 752, 480)


def _frame(
    rng: np.random.Generator, n: int, sigma_px: float, z_max: float, yaw: float = 0.0
) -> tuple[np.ndarray, ...]:
    """Points seen at k-1 (inverse depth uniform in [1/z_max, 1/2 m]), a random motion (plus
    ``yaw`` rad about the camera y axis), all four pixels with Gaussian noise. Returns the true
    R, t, the triangulated points at k-1 and the noisy pixels at k."""
    u, v = rng.uniform(20, 732, n), rng.uniform(20, 460, n)
    z = 1.0 / rng.uniform(1.0 / z_max, 0.5, n)
    P = np.c_[(u - RIG.cu) * z / RIG.f, (v - RIG.cv) * z / RIG.f, z]
    R = so3_exp(rng.normal(0.0, 0.03, 3) + np.array([0.0, yaw, 0.0]))
    t = rng.normal(0.0, 0.1, 3) + np.array([0.0, 0.0, 0.3])
    Q = P @ R.T + t
    P, Q = P[Q[:, 2] > 1.0], Q[Q[:, 2] > 1.0]

    def noisy(a: np.ndarray) -> np.ndarray:
        return a + rng.normal(0.0, sigma_px, a.shape)

    p_prev = RIG.triangulate(noisy(RIG.project(P)), noisy(RIG.project_right(P)))
    return R, t, p_prev, noisy(RIG.project(Q)), noisy(RIG.project_right(Q))


def _error(R_true: np.ndarray, t_true: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Local error (δθ, δt): R_true = R Exp(δθ), t_true = t + δt."""
    return np.r_[so3_log(R.T @ R_true), t_true - t]


def _nees(errors: list[np.ndarray], covs: list[np.ndarray]) -> np.ndarray:
    E, C = np.array(errors), np.array(covs)
    return np.einsum("ni,ni->n", E, np.linalg.solve(C, E[..., None])[..., 0])


def _band(trials: int, p: float = 0.999) -> tuple[float, float]:
    """Two-sided chi-square band of the mean of ``trials`` chi2(6) values."""
    lo, hi = chi2.ppf([(1 - p) / 2, (1 + p) / 2], 6 * trials) / trials
    return float(lo), float(hi)


def test_mean_nees_of_the_estimator_is_six() -> None:
    """200 frames, 0.2 px noise at all four pixels, 100 features within 20 m, motions with up
    to ~0.3 rad of yaw: the NEES of RANSAC + Gauss-Newton against its own covariance averages 6
    (99.9 % chi-square band of the mean) and every axis is within 35 % of 1."""
    rng = np.random.default_rng(7)
    opts = RansacOptions(pixel_sigma_px=0.2, cov_inflation=1.0)
    errors, covs = [], []
    for i in range(200):
        R, t, p_prev, uvl, uvr = _frame(rng, 100, 0.2, 20.0, yaw=0.3 * (i % 2))
        ego = estimate_egomotion(p_prev, uvl, uvr, RIG, opts, RIG.triangulate(uvl, uvr),
                                 rng=rng).egomotion
        assert ego is not None
        errors.append(_error(R, t, ego.R_Ck_Ckm1, ego.p_Ck_Ckm1))
        covs.append(ego.cov)
    nees = _nees(errors, covs)
    lo, hi = _band(nees.size)
    assert lo < nees.mean() < hi, nees.mean()
    per_axis = np.mean(np.array(errors) ** 2 / np.diagonal(np.array(covs), 0, 1, 2), axis=0)
    np.testing.assert_array_less(np.abs(per_axis - 1.0), 0.35)


def test_gate_model_accounts_for_the_inlier_cut() -> None:
    """0.5 px noise and points out to 40 m: the 1.5 px inlier gate cuts many far features and
    the fit leans on those that agree with it. Without modelling the gate the covariance is
    too small (mean NEES 8.0 here); with it the mean NEES is 3.4 (the gate model errs on the
    safe side when many features are cut, the more so since the refinement iterates until its
    inlier set settles: with two select-refine rounds it was 4.0 against 9.5 without)."""
    rng = np.random.default_rng(11)
    opts = RansacOptions(pixel_sigma_px=0.5, cov_inflation=1.0, cov_robust=False)
    errors, with_gate, without = [], [], []
    for _ in range(150):
        R, t, p_prev, uvl, uvr = _frame(rng, 150, 0.5, 40.0)
        res = estimate_egomotion(p_prev, uvl, uvr, RIG, opts, RIG.triangulate(uvl, uvr), rng=rng)
        ego = res.egomotion
        assert ego is not None
        s = res.inlier
        dv = 2.0 * (p_prev[s, 2] ** 2 / (RIG.f * RIG.baseline)) ** 2
        errors.append(_error(R, t, ego.R_Ck_Ckm1, ego.p_Ck_Ckm1))
        with_gate.append(ego.cov)
        without.append(egomotion_covariance(ego.R_Ck_Ckm1, ego.p_Ck_Ckm1, p_prev[s], uvl[s],
                                            uvr[s], RIG, 0.5, estimator_depth_var_px2=dv))
    n_gate, n_plain = _nees(errors, with_gate).mean(), _nees(errors, without).mean()
    assert 3.0 < n_gate < 8.0, n_gate
    assert n_plain > 1.8 * n_gate, (n_plain, n_gate)


def test_robust_noise_estimate_sees_through_the_gate() -> None:
    """Data noisier (0.5 px) than the configured pixel noise (0.1 px): the robust estimate,
    corrected for the features the gate cut, recovers it; the plain median of the survivors
    would not (covariance ~2x smaller). Mean NEES 3.9 (conservative, as the gate model above)."""
    rng = np.random.default_rng(5)
    opts = RansacOptions(pixel_sigma_px=0.1, cov_inflation=1.0)
    errors, covs = [], []
    for _ in range(120):
        R, t, p_prev, uvl, uvr = _frame(rng, 150, 0.5, 30.0)
        ego = estimate_egomotion(p_prev, uvl, uvr, RIG, opts, RIG.triangulate(uvl, uvr),
                                 rng=rng).egomotion
        assert ego is not None
        errors.append(_error(R, t, ego.R_Ck_Ckm1, ego.p_Ck_Ckm1))
        covs.append(ego.cov)
    assert 3.0 < _nees(errors, covs).mean() < 9.0


def test_whitened_residuals_at_the_true_motion_are_chi_square_4() -> None:
    """The four-pixel noise model (k-1 pixels through eq. 10) whitens the residuals at the true
    motion: mean 4 over many features (without the k-1 term it would be ~8)."""
    rng = np.random.default_rng(3)
    R, t, p_prev, uvl, uvr = _frame(rng, 4000, 0.3, 15.0, yaw=0.2)
    w = whitened_residuals(R, t, p_prev, uvl, uvr, RIG) / 0.3**2
    assert np.isfinite(w).all()
    assert abs(w.mean() - 4.0) < 0.25
    assert abs(np.median(w) - 3.357) < 0.25


def test_inflation_floors_the_pixel_variance_and_few_points_give_infinity() -> None:
    rng = np.random.default_rng(2)
    R, t, p_prev, uvl, uvr = _frame(rng, 80, 0.05, 15.0)
    c1 = egomotion_covariance(R, t, p_prev, uvl, uvr, RIG, 0.2, robust=True, gate_px=1.5)
    c4 = egomotion_covariance(R, t, p_prev, uvl, uvr, RIG, 0.2, robust=True, gate_px=1.5,
                              inflation=4.0)
    np.testing.assert_allclose(c4, 4.0 * c1, rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(c1) > 0)
    # Without a gate the covariance scales with the pixel variance; a gate reaching the noise
    # (0.4 px against 1.5 px) makes it grow faster.
    c2 = egomotion_covariance(R, t, p_prev, uvl, uvr, RIG, 0.4)
    c02 = egomotion_covariance(R, t, p_prev, uvl, uvr, RIG, 0.2)
    np.testing.assert_allclose(c2, 4.0 * c02, rtol=1e-9)
    c2g = egomotion_covariance(R, t, p_prev, uvl, uvr, RIG, 0.4, gate_px=1.5)
    assert np.all(np.diag(c2g) > np.diag(c2))
    inf = egomotion_covariance(R, t, p_prev[:2], uvl[:2], uvr[:2], RIG, 0.2)
    assert np.all(np.isinf(np.diag(inf)))


@pytest.mark.parametrize("bad", ["nan_point", "behind"])
def test_unusable_points_are_ignored(bad: str) -> None:
    rng = np.random.default_rng(4)
    R, t, p_prev, uvl, uvr = _frame(rng, 60, 0.1, 15.0)
    ref = egomotion_covariance(R, t, p_prev[1:], uvl[1:], uvr[1:], RIG, 0.1)
    p = p_prev.copy()
    p[0] = np.nan if bad == "nan_point" else np.array([0.0, 0.0, -5.0])
    np.testing.assert_allclose(egomotion_covariance(R, t, p, uvl, uvr, RIG, 0.1), ref)


def test_compiled_per_feature_terms_match_their_definitions() -> None:
    """``covariance_terms`` (numba) against the formulas written with numpy: J = d residual /
    d (δθ, δt) with ``q = R Exp(δθ) p + t + δt``, the estimator's weights ``W = I - c a aᵀ``,
    ``G`` from eq. 10, the sums ``Σ Jᵀ W J`` and ``Σ Jᵀ W (I + G Gᵀ) W J`` and the whitened
    residuals of ``whitened_residuals``."""
    from svains.frontend import egomotion_cov_kernels as ck
    from svains.frontend.egomotion_cov import _previous_pixel_factor, _projection_jacobian

    rng = np.random.default_rng(3)
    R, t, p, uvl, uvr = _frame(rng, 40, 0.3, 30.0, yaw=0.2)
    m = p.shape[0]
    s_e = rng.uniform(0.0, 5.0, m)
    f, b = RIG.f, RIG.baseline
    J, WJ, G = np.empty((m, 4, 6)), np.empty((m, 4, 6)), np.empty((m, 4, 3))
    e2, spread, A, B = np.empty(m), np.empty(m), np.empty((6, 6)), np.empty((6, 6))
    ck.covariance_terms(R, t, p, uvl, uvr, s_e, True, f, RIG.cu, RIG.cv, b, J, WJ, G, e2,
                        spread, A, B)  # fmt: skip
    q = p @ R.T + t
    P = _projection_jacobian(q, f, b)
    skew = np.zeros((m, 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
    skew -= np.swapaxes(skew, 1, 2)
    J_ref = np.concatenate([P @ (-R @ skew), P], axis=2)
    G_ref, ray = _previous_pixel_factor(P @ R, p, f, b)
    a = ray / p[:, 2:3]
    c = s_e / (1.0 + s_e * (a * a).sum(1))
    W = np.eye(4) - c[:, None, None] * a[:, :, None] * a[:, None, :]
    S = np.eye(4) + G_ref @ np.swapaxes(G_ref, 1, 2)
    WJ_ref = W @ J_ref
    np.testing.assert_allclose(J, J_ref, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(G, G_ref, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(WJ, WJ_ref, rtol=1e-10, atol=1e-9)
    A_ref = np.einsum("mia,mib->ab", J_ref, WJ_ref)
    B_ref = np.einsum("mia,mij,mjb->ab", WJ_ref, S, WJ_ref)
    np.testing.assert_allclose(A, A_ref, rtol=1e-10)
    np.testing.assert_allclose(B, B_ref, rtol=1e-10)
    np.testing.assert_allclose(e2, whitened_residuals(R, t, p, uvl, uvr, RIG), rtol=1e-9)
    gl = (G_ref[:, :2] ** 2).sum((1, 2))
    gr = (G_ref[:, 2:] ** 2).sum((1, 2))
    np.testing.assert_allclose(spread, 1.0 + np.maximum(gl, gr), rtol=1e-12)


def test_compiled_sandwich_matches_numpy_and_reports_singular() -> None:
    """``sandwich``: scale * sym(A⁻¹ B A⁻ᵀ) as numpy computes it, for a badly scaled A (rotation
    rows 1e6 x the translation ones); False for a singular A."""
    from svains.frontend import egomotion_cov_kernels as ck

    rng = np.random.default_rng(11)
    X = rng.normal(size=(40, 6)) * np.r_[1e3, 1e3, 1e3, 1.0, 1.0, 1.0]
    A, B = X.T @ X, np.cov(rng.normal(size=(6, 50)))
    out = np.empty((6, 6))
    assert ck.sandwich(A, B, 2.5, out)
    Ai = np.linalg.inv(A)
    ref = 2.5 * Ai @ B @ Ai.T
    np.testing.assert_allclose(out, 0.5 * (ref + ref.T), rtol=1e-9, atol=0.0)
    A[5], A[:, 5] = A[4], A[:, 4]  # two equal rows and columns
    assert not ck.sandwich(A, B, 1.0, out)
