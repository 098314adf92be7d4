"""The two-frame stereo bundle adjustment (``frontend.egomotion_bundle``): its Jacobians against
finite differences, exact recovery without noise, consistency and no bias with noise where the
RANSAC estimate is biased, outliers, degenerate input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from svains.frontend.egomotion import RansacOptions, estimate_egomotion
from svains.frontend.egomotion_bundle import BundleOptions, refine_two_frame
from svains.frontend.egomotion_bundle_kernels import _feature
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp, so3_log

RIG = RectifiedStereo(458.0, 367.0, 248.0, 0.11, np.eye(3), np.zeros(3), 752, 480)
R_TRUE = so3_exp(np.array([0.01, 0.05, -0.02]))
T_TRUE = np.array([0.08, -0.03, -0.35])


def _scene(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """Points (n, 3) m in C_{k-1}, 4-40 m deep, visible in both frames."""
    z = rng.uniform(4.0, 40.0, n)
    return np.c_[rng.uniform(-0.7, 0.7, n) * z, rng.uniform(-0.45, 0.45, n) * z, z]


def _pixels(P: np.ndarray, rng: np.random.Generator, sigma: float) -> tuple[np.ndarray, ...]:
    """Left/right pixels (n, 2) at k-1 and at k, each with white noise ``sigma`` px."""
    Q = P @ R_TRUE.T + T_TRUE
    n = len(P)

    def noisy(x: np.ndarray) -> np.ndarray:
        return x + sigma * rng.standard_normal((n, 2))

    return (noisy(RIG.project(P)), noisy(RIG.project_right(P)), noisy(RIG.project(Q)),
            noisy(RIG.project_right(Q)))  # fmt: skip


def _error(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(local rotation error rad, translation error m) of an estimate."""
    return np.concatenate([so3_log(R_TRUE.T @ R), t - T_TRUE])


def test_feature_jacobians_match_finite_differences() -> None:
    rng = np.random.default_rng(0)
    R, t = so3_exp(rng.normal(size=3) * 0.2), rng.normal(size=3)
    a = np.array([0.1, -0.2, 0.3])
    zp, zc = rng.normal(size=4) * 100 + 300, rng.normal(size=4) * 100 + 300

    def feature(R: np.ndarray, t: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, ...]:
        r, Jp, Jx = np.empty(8), np.empty((8, 3)), np.empty((4, 6))
        _feature(R, t, a, zp, zc, RIG.f, RIG.baseline, RIG.cu, RIG.cv, r, Jp, Jx)
        return r, Jp, Jx

    r0, Jp, Jx = feature(R, t, a)
    eps = 1e-6
    E = np.eye(3) * eps
    Jp_fd = np.stack([(feature(R, t, a + E[i])[0] - r0) / eps for i in range(3)], 1)
    Jx_fd = np.stack([(feature(R @ so3_exp(E[i]), t, a)[0] - r0) / eps for i in range(3)]
                     + [(feature(R, t + E[i], a)[0] - r0) / eps for i in range(3)], 1)  # fmt: skip
    np.testing.assert_allclose(Jp, Jp_fd, atol=2e-3 * np.abs(Jp).max())
    np.testing.assert_allclose(Jx, Jx_fd[4:], atol=2e-3 * np.abs(Jx).max())
    assert np.all(Jx_fd[:4] == 0.0)  # the k-1 pixels do not depend on the motion


def test_noise_free_pixels_give_the_true_motion() -> None:
    rng = np.random.default_rng(1)
    P = _scene(rng)
    l0, r0, l1, r1 = _pixels(P, rng, 0.0)
    res = refine_two_frame(R_TRUE @ so3_exp(np.array([0.003, -0.002, 0.001])),
                           T_TRUE + 0.02, l0, r0, l1, r1, RIG, np.ones(len(P), bool))  # fmt: skip
    assert res.egomotion is not None and res.egomotion.estimator == "bundle"
    np.testing.assert_allclose(_error(res.egomotion.R_Ck_Ckm1, res.egomotion.p_Ck_Ckm1), 0.0,
                               atol=1e-9)  # fmt: skip
    assert res.inlier.all()


def test_noisy_pixels_consistent_and_unbiased_where_ransac_is_not() -> None:
    """Monte Carlo over 150 seeded frames (0.5 px, 200 points): the bundle estimate's NEES
    against its own covariance is ~6 (6 dof) and its mean error is within 3 standard errors
    of zero; the RANSAC estimate from the same pixels errs more and leans one way.

    Measured 2026-12-03: bundle NEES 6.28, largest |mean| 1.2 standard errors, 99.1 % of the
    features kept; RANSAC's rms translation error 2.3x larger, its pan and x translation
    leaning 6.6 and 8.4 standard errors (it keeps 56 % of the features)."""
    rng = np.random.default_rng(2)
    e_b, e_f, nees, kept = [], [], [], []
    for _ in range(150):
        P = _scene(rng)
        l0, r0, l1, r1 = _pixels(P, rng, 0.5)
        fwd = estimate_egomotion(RIG.triangulate(l0, r0), l1, r1, RIG, RansacOptions(seed=0))
        assert fwd.egomotion is not None
        f = fwd.egomotion
        res = refine_two_frame(f.R_Ck_Ckm1, f.p_Ck_Ckm1, l0, r0, l1, r1, RIG, fwd.inlier)
        assert res.egomotion is not None
        e = _error(res.egomotion.R_Ck_Ckm1, res.egomotion.p_Ck_Ckm1)
        e_b.append(e)
        e_f.append(_error(f.R_Ck_Ckm1, f.p_Ck_Ckm1))
        nees.append(e @ np.linalg.solve(res.egomotion.cov, e))
        assert abs(res.sigma_px - 0.5) < 0.05
        kept.append(res.inlier.mean())
    eb, ef = np.array(e_b), np.array(e_f)
    assert 5.0 < np.mean(nees) < 7.2
    z_b = eb.mean(0) / (eb.std(0) / np.sqrt(len(eb)))
    assert np.abs(z_b).max() < 3.0
    z_f = ef.mean(0) / (ef.std(0) / np.sqrt(len(ef)))
    assert np.abs(z_f).max() > 4.0  # the bias this estimator is for is there
    assert np.mean(kept) > 0.98  # the joint gate keeps what the noise explains
    assert np.sqrt((eb[:, 3:] ** 2).mean()) < 0.6 * np.sqrt((ef[:, 3:] ** 2).mean())


def test_outliers_are_left_out() -> None:
    rng = np.random.default_rng(3)
    P = _scene(rng)
    l0, r0, l1, r1 = _pixels(P, rng, 0.5)
    bad = rng.random(len(P)) < 0.1
    l1[bad] += rng.choice([-1.0, 1.0], (int(bad.sum()), 2)) * rng.uniform(8, 30, (bad.sum(), 2))
    r1[bad] = l1[bad] - (l1[bad] - r1[bad])  # a wrong match moves both images alike
    res = refine_two_frame(R_TRUE, T_TRUE, l0, r0, l1, r1, RIG, np.ones(len(P), bool))
    assert res.egomotion is not None
    assert not (res.inlier & bad).any()
    assert res.inlier[~bad].mean() > 0.97
    e = _error(res.egomotion.R_Ck_Ckm1, res.egomotion.p_Ck_Ckm1)
    assert e @ np.linalg.solve(res.egomotion.cov, e) < 22.5  # chi-square 6 dof, 0.999


@pytest.mark.parametrize("case", ["few", "nan", "no_disparity"])
def test_degenerate_input_gives_no_motion_or_skips_the_feature(case: str) -> None:
    rng = np.random.default_rng(4)
    P = _scene(rng, 40)
    l0, r0, l1, r1 = _pixels(P, rng, 0.5)
    inlier = np.ones(len(P), bool)
    if case == "few":
        inlier[5:] = False
        opts = BundleOptions(min_features=8)
        res = refine_two_frame(R_TRUE, T_TRUE, l0, r0, l1, r1, RIG, inlier, opts)
        assert res.egomotion is None and not res.inlier.any()
        return
    if case == "nan":
        l1[:3] = np.nan
    else:
        r0[:3, 0] = l0[:3, 0] + 1.0  # negative disparity at k-1
    res = refine_two_frame(R_TRUE, T_TRUE, l0, r0, l1, r1, RIG, inlier)
    assert res.egomotion is not None
    assert not res.inlier[:3].any() and res.inlier[3:].mean() > 0.9


@pytest.mark.realdata
@pytest.mark.slow
def test_image_vo_on_kitti_odometry_gains_from_the_bundle(kitti_a: Path, tmp_path: Path) -> None:
    """The image front end's egomotion, bundle-adjusted (``vo``'s default) against RANSAC's
    alone, chained over the 51 real KITTI odometry frames.

    Measured 2026-12-03: ATE 0.090 m against 0.113 m, final error 0.561 m against 0.682 m."""
    from typer.testing import CliRunner

    from svains.cli.main import app

    def run(bundle: bool) -> dict:
        out = tmp_path / f"b{int(bundle)}"
        args = ["run", str(kitti_a), "--method", "vo", "--out", str(out),
                "--set", f"vision.egomotion_bundle={str(bundle).lower()}"]  # fmt: skip
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        return json.loads((out / "report.json").read_text(encoding="utf-8"))

    with_bundle, ransac = run(True), run(False)
    assert with_bundle["ate_rmse_m"] < 0.9 * ransac["ate_rmse_m"], (with_bundle, ransac)
    assert with_bundle["final_error_m"] < 0.9 * ransac["final_error_m"]
