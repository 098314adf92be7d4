"""RANSAC + Gauss-Newton stereo egomotion (eqs. 11-12) on synthetic features, and VO chaining."""

from __future__ import annotations

import numpy as np
import pytest

from svains.frontend.egomotion import (
    RansacOptions,
    estimate_egomotion,
    estimate_egomotion_widening,
    gauss_newton,
    kabsch,
)
from svains.frontend.types import Egomotion
from svains.frontend.vo_chain import chain_egomotion, relative_motion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp, so3_log

RIG = RectifiedStereo(700.0, 600.0, 180.0, 0.54, np.eye(3), np.zeros(3), 1226, 370)
R_TRUE = so3_exp([0.01, -0.02, 0.005])
T_TRUE = np.array([0.05, 0.02, -1.2])


def _scene(seed: int, n: int = 300, outlier_frac: float = 0.3, noise_px: float = 0.2):
    rng = np.random.default_rng(seed)
    p = np.c_[rng.uniform(-10, 10, n), rng.uniform(-2, 2, n), rng.uniform(4, 60, n)]
    # Triangulate k-1 from noisy pixels (realistic depth errors), measure k with noise.
    uvl0 = RIG.project(p) + rng.normal(0, noise_px, (n, 2))
    uvr0 = RIG.project_right(p) + rng.normal(0, noise_px, (n, 2))
    uvr0[:, 1] = uvl0[:, 1]
    q = p @ R_TRUE.T + T_TRUE
    uvl = RIG.project(q) + rng.normal(0, noise_px, (n, 2))
    uvr = RIG.project_right(q) + rng.normal(0, noise_px, (n, 2))
    out = rng.random(n) < outlier_frac
    shift = rng.uniform(5, 30, (n, 2)) * rng.choice([-1, 1], (n, 2))
    uvl[out] += shift[out]
    uvr[out] += shift[out]
    return RIG.triangulate(uvl0, uvr0), uvl, uvr, out


def test_ransac_recovers_motion_and_flags_outliers() -> None:
    p_prev, uvl, uvr, out = _scene(1)
    p_cur = RIG.triangulate(uvl, uvr)
    res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(), p_cur=p_cur)
    ego = res.egomotion
    assert ego is not None
    assert np.degrees(np.linalg.norm(so3_log(ego.R_Ck_Ckm1 @ R_TRUE.T))) < 0.01
    assert np.linalg.norm(ego.p_Ck_Ckm1 - T_TRUE) < 0.01
    assert not np.any(res.inlier & out)  # every displaced feature rejected
    assert (res.inlier & ~out).sum() >= 0.95 * (~out).sum()
    # Covariance: symmetric positive definite, and consistent with the actual error size.
    assert np.allclose(ego.cov, ego.cov.T)
    sd = np.sqrt(np.diag(ego.cov))
    assert np.all(np.linalg.eigvalsh(ego.cov) > 0)
    assert np.all(sd[3:] < 0.01) and np.all(sd[3:] > 1e-5)
    assert np.linalg.norm(ego.p_Ck_Ckm1 - T_TRUE) < 5 * np.linalg.norm(sd[3:])


def test_motion_only_skips_the_covariance_and_keeps_the_motion() -> None:
    """``covariance=False`` (a linearisation point): the same motion, inliers and errors, bit
    for bit, and a NaN covariance (never mistaken for a usable one)."""
    p_prev, uvl, uvr, _ = _scene(2)
    p_cur = RIG.triangulate(uvl, uvr)
    full = estimate_egomotion_widening(p_prev, uvl, uvr, RIG, RansacOptions(seed=5), p_cur=p_cur)
    only = estimate_egomotion_widening(p_prev, uvl, uvr, RIG, RansacOptions(seed=5), p_cur=p_cur,
                                       covariance=False)  # fmt: skip
    assert full.egomotion is not None and only.egomotion is not None
    np.testing.assert_array_equal(only.egomotion.R_Ck_Ckm1, full.egomotion.R_Ck_Ckm1)
    np.testing.assert_array_equal(only.egomotion.p_Ck_Ckm1, full.egomotion.p_Ck_Ckm1)
    np.testing.assert_array_equal(only.inlier, full.inlier)
    np.testing.assert_array_equal(only.error_px, full.error_px)
    assert np.isnan(only.egomotion.cov).all() and np.isfinite(full.egomotion.cov).all()


def test_ransac_works_without_triangulation_at_k_and_uses_prior() -> None:
    p_prev, uvl, uvr, out = _scene(2)
    prior = Egomotion(R_TRUE, T_TRUE, np.eye(6) * 1e-4)
    res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(iterations=5), prior=prior)
    assert res.egomotion is not None
    assert np.linalg.norm(res.egomotion.p_Ck_Ckm1 - T_TRUE) < 0.01
    assert not np.any(res.inlier & out)


def test_a_prior_explaining_most_features_is_refined_without_random_hypotheses() -> None:
    """10 % outliers and a prior 1 px off (about 0.1 deg and 1 cm): the refined prior is the
    answer (the sampler is never drawn from) and matches full RANSAC; a prior that explains
    too few features (30 % outliers with ``prior_accept_fraction`` 0.8, or a prior 20 px off)
    falls back to RANSAC and still finds the motion."""
    p_prev, uvl, uvr, out = _scene(4, outlier_frac=0.1)
    p_cur = RIG.triangulate(uvl, uvr)
    near = Egomotion(so3_exp([0.0, 0.0015, 0.0]) @ R_TRUE, T_TRUE + 0.01, np.eye(6) * 1e-4)
    rng = np.random.default_rng(5)
    before = rng.bit_generator.state
    res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(), p_cur, near, rng)
    assert rng.bit_generator.state == before  # no random triple drawn
    full = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(prior_accept_fraction=1.5),
                              p_cur, near)  # fmt: skip
    assert res.egomotion is not None and full.egomotion is not None
    assert np.array_equal(res.inlier, full.inlier)
    assert not np.any(res.inlier & out) and res.inlier.sum() >= 0.95 * (~out).sum()
    np.testing.assert_allclose(res.egomotion.p_Ck_Ckm1, full.egomotion.p_Ck_Ckm1, atol=1e-9)
    assert np.linalg.norm(res.egomotion.p_Ck_Ckm1 - T_TRUE) < 0.01
    far = Egomotion(so3_exp([0.0, 0.03, 0.0]) @ R_TRUE, T_TRUE, np.eye(6) * 1e-4)
    for prior, frac in ((far, 0.1), (near, 0.3)):
        p_prev, uvl, uvr, out = _scene(4, outlier_frac=frac)
        rng = np.random.default_rng(5)
        before = rng.bit_generator.state
        res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(),
                                 RIG.triangulate(uvl, uvr), prior, rng)  # fmt: skip
        assert rng.bit_generator.state != before  # RANSAC ran
        assert res.egomotion is not None
        assert np.linalg.norm(res.egomotion.p_Ck_Ckm1 - T_TRUE) < 0.01
        assert not np.any(res.inlier & out)


def test_degenerate_inputs_give_no_motion() -> None:
    p_prev, uvl, uvr, _ = _scene(3, n=5)
    res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions(min_inliers=8))
    assert res.egomotion is None and not res.inlier.any()
    empty = estimate_egomotion(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), RIG,
                               RansacOptions())  # fmt: skip
    assert empty.egomotion is None and empty.inlier.shape == (0,)
    # NaN points (no disparity at k-1) are never inliers; all-NaN gives no motion.
    p_prev, uvl, uvr, _ = _scene(4, outlier_frac=0.0)
    p_prev[:50] = np.nan
    res = estimate_egomotion(p_prev, uvl, uvr, RIG, RansacOptions())
    assert res.egomotion is not None and not res.inlier[:50].any() and res.inlier[50:].sum() > 200
    res = estimate_egomotion(np.full_like(p_prev, np.nan), uvl, uvr, RIG, RansacOptions())
    assert res.egomotion is None
    # Pure noise (no consistent motion): RANSAC must not invent a measurement.
    rng = np.random.default_rng(5)
    junk_l, junk_r = rng.uniform(0, 1000, (250, 2)), rng.uniform(0, 1000, (250, 2))
    res = estimate_egomotion(p_prev[50:], junk_l, junk_r, RIG, RansacOptions(min_inliers=12))
    assert res.egomotion is None


def test_gauss_newton_batch_matches_single_problems() -> None:
    p_prev, uvl, uvr, _ = _scene(6, outlier_frac=0.0, noise_px=0.0)
    P = np.stack([p_prev[:10], p_prev[10:20]])
    L = np.stack([uvl[:10], uvl[10:20]])
    R = np.stack([uvr[:10], uvr[10:20]])
    R0 = np.stack([np.eye(3), so3_exp([0.02, 0, 0])])
    Rb, tb = gauss_newton(R0, np.zeros((2, 3)), P, L, R, np.ones((2, 10)), RIG, 10)
    for h in range(2):
        Rs, ts = gauss_newton(R0[h:h + 1], np.zeros((1, 3)), P[h:h + 1], L[h:h + 1], R[h:h + 1],
                              np.ones((1, 10)), RIG, 10)  # fmt: skip
        np.testing.assert_allclose(Rb[h], Rs[0], atol=1e-12)
        np.testing.assert_allclose(tb[h], ts[0], atol=1e-12)
        # Noise-free pixels from exact depths: the true motion is recovered to numerical precision.
        np.testing.assert_allclose(Rs[0], R_TRUE, atol=1e-5)
        np.testing.assert_allclose(ts[0], T_TRUE, atol=1e-4)


def test_kabsch_exact() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(4, 5, 3))
    R = so3_exp(rng.normal(size=(4, 3)))
    t = rng.normal(size=(4, 3))
    b = np.einsum("hij,hmj->hmi", R, a) + t[:, None]
    Rk, tk = kabsch(a, b)
    np.testing.assert_allclose(Rk, R, atol=1e-10)
    np.testing.assert_allclose(tk, t, atol=1e-10)


def test_chain_egomotion_round_trip() -> None:
    rng = np.random.default_rng(8)
    T = [np.eye(4)]
    for _ in range(6):
        step = np.eye(4)
        step[:3, :3] = so3_exp(rng.normal(0, 0.1, 3))
        step[:3, 3] = rng.normal(0, 1, 3)
        T.append(T[-1] @ step)
    egos = [Egomotion(*relative_motion(T[k - 1], T[k]), np.eye(6)) for k in range(1, 7)]
    chained = chain_egomotion(egos, T[0])
    np.testing.assert_allclose(chained, np.stack(T), atol=1e-10)
    # None repeats the previous motion (constant velocity).
    c2 = chain_egomotion([egos[0], None], T[0])
    np.testing.assert_allclose(c2[2], T[1] @ np.linalg.inv(T[0]) @ T[1], atol=1e-10)
    assert chain_egomotion([], T[3]).shape == (1, 4, 4)


@pytest.mark.parametrize("seed", [11, 12])
def test_static_camera_gives_zero_motion(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p = np.c_[rng.uniform(-2, 2, 200), rng.uniform(-1, 1, 200), rng.uniform(1, 8, 200)]
    uvl, uvr = RIG.project(p), RIG.project_right(p)
    noisy = lambda a: a + rng.normal(0, 0.1, a.shape)  # noqa: E731
    res = estimate_egomotion(RIG.triangulate(noisy(uvl), noisy(uvr)), noisy(uvl), noisy(uvr),
                             RIG, RansacOptions())  # fmt: skip
    assert res.egomotion is not None
    assert np.linalg.norm(res.egomotion.p_Ck_Ckm1) < 2e-3
    assert np.degrees(np.linalg.norm(so3_log(res.egomotion.R_Ck_Ckm1))) < 0.02


def test_distinct_triples_are_distinct_and_uniform() -> None:
    from svains.frontend.egomotion import _distinct_triples

    t = _distinct_triples(np.random.default_rng(0), 60_000, 6)
    assert (t[:, 0] != t[:, 1]).all() and (t[:, 0] != t[:, 2]).all() and (t[:, 1] != t[:, 2]).all()
    assert t.min() == 0 and t.max() == 5
    s = np.sort(t, axis=1)
    _, counts = np.unique(s[:, 0] * 36 + s[:, 1] * 6 + s[:, 2], return_counts=True)
    assert counts.size == 20  # every unordered triple of 6 occurs, about equally often
    assert counts.min() > 0.9 * 3000 and counts.max() < 1.1 * 3000


# A MAV-sized rig (EuRoC: 458 px, 11 cm) turning 40 deg and moving 1 m between two frames seconds
# apart, points 1.8-3.2 m away, 0.5 px noise: the k-1 depth noise alone moves the true
# motion's reprojections by several pixels.
MAV = RectifiedStereo(458.0, 367.0, 248.0, 0.11, np.eye(3), np.zeros(3), 752, 480)
R_WIDE = so3_exp([0.0, np.radians(40.0), 0.0])
T_WIDE = np.array([0.8, 0.1, -0.6])


def _wide_scene(seed: int, n: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = np.c_[rng.uniform(-1.2, 1.2, n), rng.uniform(-0.8, 0.8, n), rng.uniform(1.8, 3.2, n)]
    p = (q - T_WIDE) @ R_WIDE  # the same points in C_k-1 (q = R p + t)
    uvl0 = MAV.project(p) + rng.normal(0, 0.5, (n, 2))
    uvr0 = MAV.project_right(p) + rng.normal(0, 0.5, (n, 2))
    uvr0[:, 1] = uvl0[:, 1]
    uvl = MAV.project(q) + rng.normal(0, 0.5, (n, 2))
    uvr = MAV.project_right(q) + rng.normal(0, 0.5, (n, 2))
    seen = (p[:, 2] > 0.5) & (uvl0[:, 0] > 0) & (uvl0[:, 0] < 752) & (uvl[:, 0] > 0)
    seen &= uvl[:, 0] < 752
    return MAV.triangulate(uvl0[seen], uvr0[seen]), uvl[seen], uvr[seen]


def test_widening_finds_a_wide_baseline_motion_and_skips_a_minority_consensus() -> None:
    p_prev, uvl, uvr = _wide_scene(5)
    p_cur = MAV.triangulate(uvl, uvr)
    assert estimate_egomotion(p_prev, uvl, uvr, MAV, RansacOptions(), p_cur=p_cur).egomotion is None
    # At 5 px a consensus exists, but of a minority (22 of 45): not taken.
    five = estimate_egomotion(p_prev, uvl, uvr, MAV, RansacOptions(inlier_px=5.0), p_cur=p_cur)
    assert five.egomotion is not None and five.inlier.sum() < 0.5 * len(p_prev)
    res = estimate_egomotion_widening(p_prev, uvl, uvr, MAV, RansacOptions(), p_cur=p_cur)
    ego = res.egomotion
    assert ego is not None and res.inlier.sum() >= 0.5 * len(p_prev)
    assert np.linalg.norm(ego.p_Ck_Ckm1 - T_WIDE) < 0.02  # 7 mm (5 px: 22 mm)
    assert np.degrees(np.linalg.norm(so3_log(ego.R_Ck_Ckm1 @ R_WIDE.T))) < 0.5


def test_widening_keeps_a_narrow_consensus_and_gives_up_on_noise() -> None:
    p_prev, uvl, uvr = _wide_scene(2)  # 1.5 px finds a motion here: no retry
    p_cur = MAV.triangulate(uvl, uvr)
    plain = estimate_egomotion(p_prev, uvl, uvr, MAV, RansacOptions(), p_cur=p_cur)
    wide = estimate_egomotion_widening(p_prev, uvl, uvr, MAV, RansacOptions(), p_cur=p_cur)
    assert plain.egomotion is not None and wide.egomotion is not None
    np.testing.assert_array_equal(wide.egomotion.p_Ck_Ckm1, plain.egomotion.p_Ck_Ckm1)
    np.testing.assert_array_equal(wide.inlier, plain.inlier)
    # Pixels unrelated to the points: no threshold finds a majority.
    rng = np.random.default_rng(0)
    noise_l = np.c_[rng.uniform(0, 752, len(p_prev)), rng.uniform(0, 480, len(p_prev))]
    noise_r = noise_l - np.c_[rng.uniform(5, 40, len(p_prev)), np.zeros(len(p_prev))]
    res = estimate_egomotion_widening(p_prev, noise_l, noise_r, MAV, RansacOptions(),
                                      p_cur=MAV.triangulate(noise_l, noise_r))
    assert res.egomotion is None and not res.inlier.any()
