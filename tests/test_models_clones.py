"""Stochastic cloning: augmented manifold, augment/marginalise, exact clone-based vision models,
and a Monte Carlo check that the clone-based 3d update is consistent on two frames."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np
import pytest

from _vision_truth import make_rig, true_pixels, two_frames
from svains.errors import ConfigError
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.geometry.rotation import quat_exp, quat_multiply, quat_to_rotmat, so3_exp
from svains.models.clones import (
    CLONE_JITTER,
    CLONE_JITTER_REL,
    CloneManifold,
    augment_calibration,
    augment_clone,
    marginalize_clone,
)
from svains.models.imu import ImuChunk, ImuModel
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, DP, DTH, PAPER
from svains.models.vision_3d import predict_pixels_3d_exact
from svains.models.vision_clone import (
    body_displacement,
    clone_camera_motion,
    predict_egomotion_clone,
    predict_pixels_3d_clone,
    predict_pixels_tc_clone,
)
from svains.models.vision_lc import egomotion_from_state_pair
from svains.navigation.vision_noise import analytic_noise

RIG = make_rig()
OMEGA_B = np.array([0.3, -0.5, 0.8])
A_W = np.array([0.5, -0.4, 0.3])


def _random_state(rng: np.random.Generator, layout=BIASED) -> tuple[np.ndarray, np.ndarray]:
    x = rng.normal(size=layout.nx)
    x[6:10] /= np.linalg.norm(x[6:10])
    A = rng.normal(size=(layout.ndx, layout.ndx)) * 0.1
    return x, A @ A.T + 1e-3 * np.eye(layout.ndx)


def test_augment_copies_pose_and_covariance_exactly() -> None:
    rng = np.random.default_rng(0)
    x, P = _random_state(rng)
    m0 = CloneManifold(NavManifold(BIASED), 0)
    x1, P1, m1 = augment_clone(x, P, m0)
    cp, cq = m1.columns(0)
    np.testing.assert_array_equal(x1[cp], x[0:3])
    np.testing.assert_array_equal(x1[cq], x[6:10])
    n = BIASED.ndx
    pose = np.r_[np.arange(n)[DP], np.arange(n)[DTH]]
    np.testing.assert_allclose(P1[:n, :n], P, atol=1e-15)
    np.testing.assert_allclose(P1[n:, :n], P[pose], atol=1e-15)
    jitter = np.maximum(CLONE_JITTER, CLONE_JITTER_REL * np.diag(P)[pose])
    np.testing.assert_array_equal(jitter, CloneManifold.clone_jitter(np.diag(P)[pose]))
    np.testing.assert_allclose(P1[n:, n:], P[np.ix_(pose, pose)] + np.diag(jitter), rtol=1e-15)
    assert np.allclose(P1, P1.T, atol=0.0)
    assert np.linalg.eigvalsh(P1).min() > 0.0  # positive definite thanks to the jitter


@pytest.mark.parametrize("seed", range(8))
def test_clone_jitter_is_relative_to_the_variances_it_copies(seed: int) -> None:
    # 100 m position deviations (variance 1e4 m²): an absolute 1e-12 would sit below the
    # rounding of the factorisation (eps · 1e4), and the plain Cholesky factor would fail.
    rng = np.random.default_rng(seed)
    x, P = _random_state(rng)
    s = np.ones(BIASED.ndx)
    s[DP] = 100.0 * np.sqrt(3.0)
    P = s[:, None] * P * s[None, :]
    m0 = CloneManifold(NavManifold(BIASED), 0)
    x1, P1, m1 = augment_clone(x, P, m0)
    n = BIASED.ndx
    pose = np.r_[np.arange(n)[DP], np.arange(n)[DTH]]
    v = np.diag(P)[pose]
    np.testing.assert_allclose(np.diag(P1)[n:] - v, np.maximum(1e-12, 1e-9 * v), rtol=1e-6)
    assert (np.diag(P1)[n:] - v)[:3].min() > 1e-6  # position: 1e-9 of ~1e4 m²
    np.linalg.cholesky(P1)  # positive definite without any repair
    _, P2, _ = augment_clone(x1, P1, m1)  # a second clone of the same pose
    np.linalg.cholesky(P2)
    _, P0, _ = augment_clone(x, P, m0, jitter=0.0)  # an explicit jitter is absolute
    np.testing.assert_array_equal(P0[n:, n:], P[np.ix_(pose, pose)])


def test_marginalize_undoes_augment_and_picks_the_right_clone() -> None:
    rng = np.random.default_rng(1)
    x, P = _random_state(rng, PAPER)
    m = CloneManifold(NavManifold(PAPER), 0)
    xa, Pa, ma = augment_clone(x, P, m)
    x_moved = xa.copy()
    x_moved[0:3] += 1.0  # the navigation block moves on; clone 0 keeps the old pose
    xb, Pb, mb = augment_clone(x_moved, Pa, ma)
    xc, _, mc = marginalize_clone(xb, Pb, mb, 0)  # drop the older clone
    assert mc.n_clones == 1
    np.testing.assert_array_equal(xc[mc.columns(0)[0]], x_moved[0:3])
    xd, Pd, md = marginalize_clone(xa, Pa, ma, 0)
    np.testing.assert_array_equal(xd, x)
    np.testing.assert_array_equal(Pd, P)
    assert md.n_clones == 0
    with pytest.raises(ConfigError, match="clone index 3 out of range"):
        marginalize_clone(xa, Pa, ma, 3)


def test_clone_manifold_retract_local_mean_are_consistent() -> None:
    rng = np.random.default_rng(2)
    x, P = _random_state(rng)
    m = CloneManifold(NavManifold(BIASED), 0)
    for _ in range(2):
        x, P, m = augment_clone(x, P, m)
    dX = rng.normal(scale=0.1, size=(7, m.ndx))
    X = m.retract(np.broadcast_to(x, (7, m.nx)), dX)
    np.testing.assert_allclose(m.local(X, x), dX, atol=1e-12)
    # The mean of symmetric offsets is the centre.
    Xs = m.retract(np.broadcast_to(x, (14, m.nx)), np.vstack([dX, -dX]))
    np.testing.assert_allclose(m.local(m.mean(Xs, np.full(14, 1 / 14))[None], x), 0.0, atol=1e-6)


def test_process_model_leaves_clones_unchanged_and_noise_covers_navigation_only() -> None:
    rng = np.random.default_rng(3)
    x, P = _random_state(rng)
    x[3:6] = [1.0, 0.0, 0.0]
    m = CloneManifold(NavManifold(BIASED), 0)
    x, P, m = augment_clone(x, P * 1e-2, m)
    chunk = ImuChunk(np.full(4, 0.01), np.full((5, 3), 0.1), np.tile([0, 0, 9.81], (5, 1)),
                     np.zeros((5, 3)))
    for pre in (True, False):
        f = ImuModel(BIASED, np.array([0, 0, -9.81]), np.array([0.01, 0.0, 0.0]), pre)
        ukf = UKF(m, MerweScaledSigmaPoints(m.ndx), x, P)
        ukf.predict(f, chunk, 0.0, np.eye(BIASED.ndx) * 1e-4)
        n = BIASED.ndx
        np.testing.assert_allclose(ukf.x[BIASED.nx :], x[BIASED.nx :], atol=1e-12)
        np.testing.assert_allclose(ukf.P[n:, n:], P[n:, n:], atol=1e-12)
        assert not np.allclose(ukf.x[0:3], x[0:3])  # the navigation block did move
    with pytest.raises(ConfigError, match="process noise of size 40"):
        ukf.predict(f, chunk, 0.0, np.eye(40))


def _augmented(tf) -> tuple[np.ndarray, tuple[slice, slice]]:
    """13-number state at k followed by one clone of the pose at k-1."""
    x = np.concatenate([tf.x_k, tf.x_km1[0:3], tf.x_km1[6:10]])
    return x, (slice(13, 16), slice(16, 20))


def test_clone_models_are_exact() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    x, cols = _augmented(tf)
    pix = predict_pixels_3d_clone(x, tf.p_Ckm1_F, cols, RIG)
    np.testing.assert_allclose(pix, true_pixels(tf), atol=1e-9)
    ref = predict_pixels_3d_exact(tf.x_k, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1, tf.p_W_Bkm1)
    np.testing.assert_allclose(pix, ref, atol=1e-10)
    tc = predict_pixels_tc_clone(x, tf.uv_left_prev, tf.uv_right_prev, cols, RIG)
    np.testing.assert_allclose(tc, true_pixels(tf), atol=1e-8)
    R, p = egomotion_from_state_pair(tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]),
                                     tf.x_k[0:3], RIG)
    ego = predict_egomotion_clone(x, cols, RIG)
    from svains.geometry.rotation import so3_log

    np.testing.assert_allclose(ego, np.r_[so3_log(R), p], atol=1e-12)


def _clone_3d_nees(seed: int, prior_scale: float, iterations: int, trials: int) -> float:
    """Mean posterior NEES (12 dof, the two poses) of one clone-based 3d update over ``trials``
    draws: a prior on (state at k, clone at k-1) with cross-covariance, about ``prior_scale``
    mm / mrad, noisy pixels at both frames, the analytic pixel noise."""
    rng = np.random.default_rng(seed)
    tf = two_frames(RIG, 0.2, OMEGA_B, A_W, n_features=30)
    x_true0, cols = _augmented(tf)
    m = CloneManifold(NavManifold(PAPER), 1)
    A = rng.normal(size=(m.ndx, m.ndx)) * 1e-3 * prior_scale
    P = A @ A.T + 1e-6 * prior_scale**2 * np.eye(m.ndx)
    L = np.linalg.cholesky(P)
    sigma = 0.5
    pose = np.r_[0:3, 6:9, 12:18]
    nees = []
    for _ in range(trials):
        # Truth = estimate ⊞ error, error ~ N(0, P).
        x_hat = m.retract(x_true0[None], (L @ rng.normal(size=m.ndx))[None])[0]
        noise0 = rng.normal(scale=sigma, size=(2, 30, 2))
        uvl0, uvr0 = tf.uv_left_prev + noise0[0], tf.uv_right_prev + noise0[1]
        z = true_pixels(tf) + rng.normal(scale=sigma, size=120)
        p_F = RIG.triangulate(uvl0, uvr0)
        R_c, r_c = _motion_at(x_hat, cols)
        R_blocks, _ = analytic_noise(R_c, r_c, uvl0, uvr0, RIG, sigma, p_Ckm1_F=p_F)
        Rm = np.zeros((120, 120))
        for i in range(30):
            Rm[4 * i : 4 * i + 4, 4 * i : 4 * i + 4] = R_blocks[i]
        ukf = UKF(m, MerweScaledSigmaPoints(m.ndx), x_hat, P)
        h = partial(predict_pixels_3d_clone, p_Ckm1_F=p_F, clone=cols, rig=RIG)
        ukf.update(h, z, Rm, iterations=iterations)
        e = m.local(x_true0[None], ukf.x)[0][pose]
        nees.append(e @ np.linalg.solve(ukf.P[np.ix_(pose, pose)], e))
    return float(np.mean(nees))


@pytest.mark.parametrize("seed", [0])
def test_clone_3d_update_is_consistent_monte_carlo(seed: int) -> None:
    """Two frames, one UKF update with the clone-based 3d model: with a prior of about 1 mm /
    1 mrad (one frame after an update) the posterior NEES averages its 12 dof."""
    mean = _clone_3d_nees(seed, 1.0, 1, 200)
    # 200 trials of a 12-dof chi-square: the mean has std sqrt(24/200) = 0.35.
    assert 12.0 - 1.5 < mean < 12.0 + 1.5, mean


def test_iterating_the_clone_3d_update_narrows_a_wide_prior_overconfidence() -> None:
    # A 10x wider prior (10 mrad, as after an IMU gap): one linearisation spans the prior, not
    # the posterior, and the NEES reaches ~28; three posterior linearisations bring it to
    # ~20 (still above 12: the pixel noise is evaluated at the prior mean).
    single = _clone_3d_nees(0, 10.0, 1, 100)
    iterated = _clone_3d_nees(0, 10.0, 3, 100)
    assert single > 20.0
    assert iterated < 0.8 * single


def _motion_at(x: np.ndarray, cols: tuple[slice, slice]) -> tuple[np.ndarray, np.ndarray]:
    from svains.models.vision_clone import clone_camera_motion

    R_c, r_c = clone_camera_motion(x, cols, RIG)
    return R_c[0], r_c[0]


def test_calibration_block_sits_between_navigation_and_clones() -> None:
    """``augment_calibration`` inserts δφ_C after the navigation block, uncorrelated; clones
    keep working behind it and the manifold operations stay consistent."""
    rng = np.random.default_rng(4)
    x, P = _random_state(rng)
    m = CloneManifold(NavManifold(BIASED), 0)
    x, P, m = augment_clone(x, P, m)
    phi = np.array([0.01, -0.02, 0.005])
    xc, Pc, mc = augment_calibration(x, P, m, phi, 1e-4 * np.eye(3))
    assert (mc.nx, mc.ndx, mc.n_calib) == (BIASED.nx + 3 + 7, BIASED.ndx + 3 + 6, 3)
    cx, cdx = mc.calib  # type: ignore[misc]
    np.testing.assert_array_equal(xc[cx], phi)
    np.testing.assert_array_equal(xc[mc.columns(0)[0]], x[m.columns(0)[0]])
    keep = np.r_[0 : cdx.start, cdx.stop : mc.ndx]
    np.testing.assert_array_equal(Pc[np.ix_(keep, keep)], P)
    np.testing.assert_array_equal(Pc[cdx, cdx], 1e-4 * np.eye(3))
    assert not Pc[cdx][:, keep].any()
    xd, _, md = augment_clone(xc, Pc, mc)  # a second clone goes behind the first
    np.testing.assert_array_equal(xd[md.columns(1)[1]], xc[6:10])
    xe, _, me = marginalize_clone(xd, augment_clone(xc, Pc, mc)[1], md, 0)
    np.testing.assert_array_equal(xe[me.calib[0]], phi)  # type: ignore[index]
    dX = rng.normal(scale=0.1, size=(5, md.ndx))
    X = md.retract(np.broadcast_to(xd, (5, md.nx)), dX)
    np.testing.assert_allclose(md.local(X, xd), dX, atol=1e-12)
    np.testing.assert_allclose(md.mean(X, np.full(5, 0.2))[md.calib[0]],  # type: ignore[index]
                               phi + dX[:, md.calib[1]].mean(axis=0), atol=1e-15)  # type: ignore[index]
    with pytest.raises(ConfigError, match="already has a calibration block of 3"):
        augment_calibration(xc, Pc, mc, phi, np.eye(3))


def test_auxiliary_block_sits_between_calibration_and_clones() -> None:
    """An auxiliary block (a bias alarm's step) goes after the calibration and before the
    clones; calibration added later is inserted before it; the manifold operations hold."""
    rng = np.random.default_rng(5)
    x, P = _random_state(rng)
    m = CloneManifold(NavManifold(BIASED), 0)
    x, P, m = augment_clone(x, P, m)
    n_aux = 4
    ma = m.with_aux(n_aux)
    aux = np.array([0.1, -0.2, 0.3, 0.4])
    a = BIASED.nx
    xa = np.concatenate([x[:a], aux, x[a:]])
    assert (ma.nx, ma.ndx, ma.n_euclid) == (m.nx + n_aux, m.ndx + n_aux, n_aux)
    assert ma.calib is None
    assert ma.aux == (slice(a, a + n_aux), slice(BIASED.ndx, BIASED.ndx + n_aux))
    np.testing.assert_array_equal(xa[ma.columns(0)[0]], x[m.columns(0)[0]])
    np.testing.assert_array_equal(xa[ma.columns(0)[1]], x[m.columns(0)[1]])
    assert ma.tangent(0) == slice(BIASED.ndx + n_aux, BIASED.ndx + n_aux + 6)
    Pa = np.eye(ma.ndx)
    xc, _, mc = augment_calibration(xa, Pa, ma, np.full(3, 0.01), 1e-4 * np.eye(3))
    assert (mc.n_calib, mc.n_aux) == (3, n_aux) and mc.calib[0] == slice(a, a + 3)  # type: ignore[index]
    np.testing.assert_array_equal(xc[mc.aux[0]], aux)  # type: ignore[index]
    xd, _, md = augment_clone(xc, np.eye(mc.ndx), mc)
    assert md.n_aux == n_aux and md.n_clones == 2
    np.testing.assert_array_equal(xd[md.columns(0)[0]], x[m.columns(0)[0]])
    dX = rng.normal(scale=0.1, size=(5, md.ndx))
    X = md.retract(np.broadcast_to(xd, (5, md.nx)), dX)
    np.testing.assert_allclose(md.local(X, xd), dX, atol=1e-12)
    np.testing.assert_allclose(X[:, md.aux[0]], aux + dX[:, md.aux[1]], atol=1e-15)  # type: ignore[index]
    np.testing.assert_allclose(md.mean(X, np.full(5, 0.2))[md.aux[0]],  # type: ignore[index]
                               aux + dX[:, md.aux[1]].mean(axis=0), atol=1e-15)  # type: ignore[index]


def test_clone_motion_with_rotation_correction_equals_the_turned_rig() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    x, cols = _augmented(tf)
    phi = np.array([0.004, -0.006, 0.002])
    x_cal = np.concatenate([x[:13], phi, x[13:]])
    cols_cal = (slice(16, 19), slice(19, 23))
    turned = replace(RIG, R_B_C=RIG.R_B_C @ so3_exp(phi))
    R_a, r_a = clone_camera_motion(x_cal, cols_cal, RIG, slice(13, 16))
    R_b, r_b = clone_camera_motion(x, cols, turned)
    np.testing.assert_allclose(R_a, R_b, atol=1e-14)
    np.testing.assert_allclose(r_a, r_b, atol=1e-14)
    _, r_0 = clone_camera_motion(x, cols, RIG)
    assert np.abs(r_a - r_0).max() > 1e-4  # the correction does move the prediction
    np.testing.assert_allclose(
        predict_egomotion_clone(x_cal, cols_cal, RIG, slice(13, 16)),
        predict_egomotion_clone(x, cols, turned), atol=1e-14)


def test_body_displacement_inverts_the_clone_camera_motion() -> None:
    """The body's displacement recovered from the left camera's motion is the state's
    ``R_k^T (p_k - p_km1)``, the lever arm and the camera's mounting rotation included."""
    assert np.linalg.norm(RIG.p_B_C) > 0.01 and not np.allclose(RIG.R_B_C, np.eye(3))
    rng = np.random.default_rng(11)
    x, P = _random_state(rng)
    x, P, m = augment_clone(x, P, CloneManifold(NavManifold(BIASED), 0))
    cols = m.columns(0)
    x[0:3] += [0.4, -0.3, 0.1]  # the body moved and turned since the clone
    x[6:10] = quat_multiply(x[6:10], quat_exp(np.array([0.05, -0.1, 0.3])))
    R_c, r_c = _motion_at(x, cols)
    R_k = quat_to_rotmat(x[6:10])
    expected = R_k.T @ (x[0:3] - x[cols[0]])
    np.testing.assert_allclose(body_displacement(R_c, -r_c, RIG), expected, atol=1e-12)
