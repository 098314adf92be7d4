"""Vision updaters (tc, 3d, lc) on one exact stereo frame pair, with the real UKF."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _nav_feed import updater_for
from _vision_truth import TwoFrames, make_rig, two_frames
from svains.datasets.types import CameraCalib, Dataset, FeatureStream
from svains.errors import ConfigError
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.models.manifold import NavManifold
from svains.models.state import PAPER, V
from svains.navigation.base import FrameContext
from svains.navigation.options import RunOptions, VisionOptions

RIG = make_rig()
T0 = 5_000_000_000
DT_S = 0.2
# The paper's state-at-k model (one frame pair, no clone needed).


def _calibs() -> tuple[CameraCalib, CameraCalib]:
    T0_ = np.eye(4)
    T0_[:3, :3], T0_[:3, 3] = RIG.R_B_C, RIG.p_B_C
    T1_ = T0_.copy()
    T1_[:3, 3] = RIG.p_B_C + RIG.R_B_C @ np.array([RIG.baseline, 0.0, 0.0])
    intr = np.array([RIG.f, RIG.f, RIG.cu, RIG.cv])
    mk = lambda n, T: CameraCalib(n, T, 2.0, (RIG.width, RIG.height), intr, "radtan", np.zeros(4))  # noqa: E731
    return mk("cam0", T0_), mk("cam1", T1_)


def _dataset(tf: TwoFrames, corrupt: int = 0, seed: int = 0) -> Dataset:
    m = len(tf.p_Ckm1_F)
    uvl = tf.uv_left.copy()
    # Columns only: rows stay on the epipolar line, so only the innovation gate can catch them.
    uvl[:corrupt, 0] += np.random.default_rng(seed).choice([-40.0, 40.0], corrupt)
    fs = FeatureStream(
        t_ns=np.repeat(np.array([T0, T0 + int(DT_S * 1e9)], np.int64), m),
        track_id=np.tile(np.arange(m, dtype=np.int64), 2),
        uv_left=np.vstack([tf.uv_left_prev, uvl]),
        uv_right=np.vstack([tf.uv_right_prev, tf.uv_right]),
        pixel_noise_std=0.3,
    )
    cam0, cam1 = _calibs()
    return Dataset(root=Path("memory"), name="two-frames", cam0=cam0, cam1=cam1, features=fs)


def _ukf(x_true: np.ndarray, dv: np.ndarray) -> UKF:
    x0 = x_true.copy()
    x0[V] += dv
    P0 = np.diag(np.r_[np.full(3, 0.01), np.full(3, 0.25), np.full(3, 1e-4), np.full(3, 1e-3)])
    return UKF(NavManifold(PAPER), MerweScaledSigmaPoints(12), x0, P0)


def _ctx(ukf: UKF) -> FrameContext:
    return FrameContext(ukf, PAPER, T0 + int(DT_S * 1e9), T0, None, [], None)  # type: ignore[arg-type]


@pytest.mark.parametrize("method", ["3d", "tc", "lc"])
def test_update_pulls_velocity_towards_truth(method: str) -> None:
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    upd = updater_for(method, _dataset(tf), VisionOptions(rotation="linear"))
    assert list(upd.frame_times) == [T0 + int(DT_S * 1e9)]
    ukf = _ukf(tf.x_k, np.array([0.4, -0.3, 0.2]))
    stats = upd.update(_ctx(ukf))
    assert stats is not None and stats.accepted
    err = np.linalg.norm(ukf.x[V] - tf.x_k[V])
    # 0.54 m/s prior error; one frame of noise-free features removes most of it.
    assert err < 0.1, err
    assert upd.summary()["frames_fused"] == 1


@pytest.mark.parametrize("method", ["3d", "tc", "lc"])
def test_clone_update_pulls_position_towards_truth(method: str) -> None:
    """Pose clones: after ``after_frame`` at k-1 the state carries the k-1 pose; the state is
    then moved to k with a 0.3 m position error (as a propagation would, with its variance),
    and the frame's update measures the k-1 -> k motion against the clone."""
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    upd = updater_for(method, _dataset(tf),
                      VisionOptions(rotation="clone", min_disparity_px=0.0, shared_pixels=False))
    ukf = _ukf(tf.x_km1, np.zeros(3))
    ctx0 = FrameContext(ukf, PAPER, T0, None, None, [], None)  # type: ignore[arg-type]
    upd.after_frame(ctx0)
    assert ukf.x.size == 13 + 7 and upd.clones.times == [T0]
    np.testing.assert_array_equal(ukf.x[13:16], tf.x_km1[0:3])
    x = ukf.x.copy()
    x[:13] = tf.x_k
    x[0:3] += [0.3, -0.2, 0.1]
    P = ukf.P.copy()
    P[0:3, 0:3] += 0.1 * np.eye(3)  # the propagation's own position uncertainty
    ukf.resize(ukf.manifold, x, P)
    stats = upd.update(_ctx(ukf))
    assert stats is not None and stats.accepted
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 0.02
    # The next frame will start from this one: its clone replaces the old one.
    upd.after_frame(_ctx(ukf))
    assert upd.clones.times == [T0 + int(DT_S * 1e9)] and ukf.x.size == 20


def test_clone_update_skips_a_frame_without_clone() -> None:
    tf = two_frames(RIG, DT_S, np.zeros(3), np.zeros(3), n_features=60)
    upd = updater_for("3d", _dataset(tf), VisionOptions())  # the default: clones
    ukf = _ukf(tf.x_k, np.zeros(3))
    assert upd.update(_ctx(ukf)) is None
    assert upd.summary()["frames_without_tracks"] == 1


def test_feature_gate_drops_and_counts_corrupted_features() -> None:
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    upd = updater_for("3d", _dataset(tf, corrupt=5), VisionOptions(rotation="linear"))
    ukf = _ukf(tf.x_k, np.array([0.05, -0.05, 0.02]))
    stats = upd.update(_ctx(ukf))
    assert stats is not None and stats.accepted
    s = upd.summary()
    assert s["features_gated"] == 5 and s["features_fused"] == 55, s
    assert np.linalg.norm(ukf.x[V] - tf.x_k[V]) < 0.04  # prior error 0.073 m/s


def test_no_tracks_gives_no_update() -> None:
    tf = two_frames(RIG, DT_S, np.zeros(3), np.zeros(3), n_features=2)
    upd = updater_for("3d", _dataset(tf), VisionOptions(rotation="linear"))
    ukf = _ukf(tf.x_k, np.zeros(3))
    x_before = ukf.x.copy()
    assert upd.update(_ctx(ukf)) is None
    np.testing.assert_array_equal(ukf.x, x_before)
    assert upd.summary()["frames_without_tracks"] == 1


def test_unknown_option_is_rejected() -> None:
    from svains.navigation.config_io import with_settings
    from svains.navigation.options import RunConfig

    with pytest.raises(ConfigError, match=r"unknown configuration key 'vision.pixel_sigma'"):
        with_settings(RunConfig(), {"vision.pixel_sigma": 1.0})
    with pytest.raises(ConfigError, match=r"vision\.rotation must be one of"):
        VisionOptions(rotation="cubic")


def test_whitening_turns_noise_into_identity() -> None:
    from svains.navigation.vision_noise import lowrank_whiten, whiten

    rng = np.random.default_rng(4)
    A = rng.normal(size=(3, 4, 4))
    R_blocks = A @ np.swapaxes(A, 1, 2) + np.eye(4)
    G = rng.normal(size=(12, 6))
    W_inv = np.linalg.inv(np.linalg.cholesky(R_blocks))
    R_full = np.zeros((12, 12))
    for k in range(3):
        R_full[4 * k : 4 * k + 4, 4 * k : 4 * k + 4] = R_blocks[k]
    R_full += G @ G.T
    # T = transform applied to every stacked vector; T R T^T must be the identity.
    Gw = whiten(G.T, W_inv).T
    T = lowrank_whiten(whiten(np.eye(12), W_inv), Gw).T  # rows transformed -> transpose
    np.testing.assert_allclose(T @ R_full @ T.T, np.eye(12), atol=1e-10)
    # The updater's form: the Cholesky factors (forward substitution), same transform.
    from svains.navigation.vision_noise import whiten_chol

    L = np.linalg.cholesky(R_blocks)
    Y = rng.normal(size=(5, 12))
    np.testing.assert_allclose(whiten_chol(Y, L), whiten(Y, W_inv), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(whiten_chol(Y[0], L), whiten(Y[0], W_inv), rtol=1e-12, atol=1e-12)
    # Diagonal factors (the two-view blocks) take a division: the same numbers.
    D = np.broadcast_to(np.diag([0.5, 2.0, 1.0, 4.0]), (3, 4, 4))
    np.testing.assert_allclose(whiten_chol(Y, D), whiten(Y, np.linalg.inv(D)), rtol=1e-15)


def test_previous_pixel_noise_is_identity_map_without_motion() -> None:
    from svains.models.vision_3d import predict_pixels_3d
    from svains.navigation.vision_noise import previous_pixel_noise

    tf = two_frames(RIG, DT_S, np.zeros(3), np.zeros(3), n_features=5)
    x = tf.x_k.copy()
    x[3:6] = 0.0  # at rest: predicted pixels at k = tracked pixels at k-1

    def h_prev(uvl: np.ndarray, uvr: np.ndarray) -> np.ndarray:
        return predict_pixels_3d(x, RIG.triangulate(uvl, uvr), DT_S, RIG)

    R = previous_pixel_noise(h_prev, tf.uv_left_prev, tf.uv_right_prev, 0.5)
    # d(uL, vL, uR, vR at k)/d(uL, vL, uR at k-1): vR follows vL in a rectified pair.
    J = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0]])
    np.testing.assert_allclose(R, np.broadcast_to(0.25 * (np.eye(4) + J @ J.T), R.shape),
                               atol=1e-6)


@pytest.mark.parametrize("rotation", ["linear", "imu"])
def test_analytic_noise_matches_finite_differences(rotation: str) -> None:
    from _vision_truth import imu_samples
    from svains.models.vision_3d import predict_pixels_3d
    from svains.models.vision_common import camera_motion
    from svains.models.vision_imu import imu_increment
    from svains.navigation.vision_noise import (
        analytic_noise,
        increment_noise_factor,
        previous_pixel_noise,
    )

    omega, acc, g = np.array([0.1, -0.2, 0.3]), np.array([0.3, 0.1, 0.0]), np.array([0, 0, -9.81])
    tf = two_frames(RIG, DT_S, omega, acc, n_features=20)
    inc = None
    if rotation == "imu":
        t_ns, gyro, accel = imu_samples(tf, omega, acc, g)
        inc = imu_increment(t_ns, gyro, accel, 0, int(DT_S * 1e9), g)
    x = tf.x_k[None, :]

    def h_prev(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return predict_pixels_3d(x, RIG.triangulate(a, b), DT_S, RIG, rotation, inc)[0]

    R_fd = previous_pixel_noise(h_prev, tf.uv_left_prev, tf.uv_right_prev, 0.5)
    R_c, r_c = camera_motion(x, DT_S, RIG, rotation, inc)
    dens = (0.01, 0.05)
    R_an, G_an = analytic_noise(R_c[0], r_c[0], tf.uv_left_prev, tf.uv_right_prev, RIG, 0.5,
                                inc, DT_S, dens)
    np.testing.assert_allclose(R_an, R_fd, rtol=1e-5, atol=1e-6)
    if inc is not None:
        G_fd = increment_noise_factor(
            lambda i: predict_pixels_3d(x, tf.p_Ckm1_F, DT_S, RIG, "imu", i)[0], inc, DT_S, *dens
        )
        assert G_an is not None
        np.testing.assert_allclose(G_an, G_fd, rtol=1e-4, atol=1e-6)


def test_tune_for_frames_sets_frame_gyro_walk() -> None:
    from dataclasses import replace

    from svains.navigation.vision import tune_for_frames
    from svains.sensors.types import ImuCalib

    cal = ImuCalib(np.eye(4), 200.0, 1.7e-4, 2e-5, 2e-3, 3e-3)
    opts = RunOptions(method="3d", model="biased", vision=VisionOptions(rotation="imu"))
    assert tune_for_frames(replace(opts, vision=VisionOptions()), cal, 0.05).noise == opts.noise
    tuned = tune_for_frames(opts, cal, 0.05)
    assert tuned.noise.gyro_random_walk == pytest.approx(1.7e-4 / 0.05)
    assert tuned.vision.imu_noise is False
    assert tune_for_frames(tuned, cal, 0.05) == tuned  # idempotent (a written config re-read)
    assert tune_for_frames(replace(opts, method="vo"), cal, 0.05).noise == opts.noise
    paper = replace(opts, vision=VisionOptions(rotation="linear"))
    assert tune_for_frames(paper, cal, 0.05) is paper


@pytest.mark.parametrize(("method", "tolerance"), [("3d", 0.2), ("lc", 0.35)])
def test_online_extrinsic_rotation_moves_towards_the_true_camera(
    method: str, tolerance: float
) -> None:
    """Pixels from a camera turned by ``phi`` against the nominal calibration: with
    ``estimate_extrinsics`` and a well-known pose, one frame pair's update explains the motion
    in camera axes by the rotation correction, which moves most of the way to ``phi``."""
    from dataclasses import replace

    from svains.geometry.rotation import so3_exp

    phi = np.radians([0.4, -0.3, 0.2])
    turned = replace(RIG, R_B_C=RIG.R_B_C @ so3_exp(phi))
    tf = two_frames(turned, DT_S, np.array([0.3, -0.4, 0.2]), np.zeros(3), n_features=80)
    # lc without its accuracy allowance (``lc_cov_scale``): one noise-free egomotion.
    opts = VisionOptions(rotation="clone", min_disparity_px=0.0, shared_pixels=False,
                         estimate_extrinsics=True,
                         lc_cov_scale=1.0)
    upd = updater_for(method, _dataset(tf), opts)
    ukf = UKF(NavManifold(PAPER), MerweScaledSigmaPoints(12), tf.x_km1.copy(),
              np.eye(12) * 1e-10)
    upd.after_frame(FrameContext(ukf, PAPER, T0, None, None, [], None))  # type: ignore[arg-type]
    assert ukf.x.size == 13 + 3 + 7  # navigation, δφ_C, one clone
    x = ukf.x.copy()
    x[:13] = tf.x_k
    ukf.resize(ukf.manifold, x, ukf.P)
    stats = upd.update(_ctx(ukf))
    assert stats is not None and stats.accepted
    upd.after_frame(_ctx(ukf))
    est = np.radians(upd.summary()["extrinsic_rotation_deg"])
    # lc measures 6 numbers per frame against 3d's 4 per feature: it gets less far.
    assert np.linalg.norm(est - phi) < tolerance * np.linalg.norm(phi), np.degrees(est)


def test_online_extrinsics_need_clones() -> None:
    with pytest.raises(ConfigError, match=r"estimate_extrinsics needs vision\.rotation=clone"):
        VisionOptions(rotation="imu", estimate_extrinsics=True)
    with pytest.raises(ConfigError, match="extrinsics_std_deg must be positive"):
        VisionOptions(extrinsics_std_deg=0.0)


def test_previous_pixel_bias_matches_the_mean_over_pixel_noise() -> None:
    from svains.geometry.camera import RectifiedStereo
    from svains.geometry.rotation import so3_exp
    from svains.models.vision_3d import pixels_from_motion
    from svains.navigation.vision_noise import previous_pixel_bias

    rig = RectifiedStereo(458.654, 367.2, 248.4, 0.11, np.eye(3), np.zeros(3), 752, 480)
    rng = np.random.default_rng(7)
    p_F = np.column_stack([rng.uniform(-3, 3, 6), rng.uniform(-2, 2, 6), rng.uniform(3, 8, 6)])
    R_c, r_c = so3_exp(np.array([0.01, 0.02, -0.01]))[None], np.array([[0.05, -0.02, 0.8]])
    uvl, uvr = rig.project(p_F), rig.project_right(p_F)

    def h_prev(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return pixels_from_motion(R_c, r_c, rig.triangulate(a, b), rig)[0]

    sigma = 0.5
    bias = previous_pixel_bias(h_prev, uvl, uvr, sigma)
    # Monte Carlo: the mean prediction from noisy k-1 pixels minus the noise-free prediction.
    n = 20_000
    nl, nr = sigma * rng.standard_normal((2, n, 6, 2))
    Y = np.stack([h_prev(uvl + nl[i], uvr + nr[i]) for i in range(n)])
    mc = Y.mean(axis=0) - h_prev(uvl, uvr)
    se = Y.std(axis=0) / np.sqrt(len(Y))
    assert np.abs(bias).max() > 0.02  # a real effect: 1 m forward at 3-8 m depth
    assert np.all(np.abs(bias - mc) < 4 * se + 2e-3)

    # At rest the prediction is linear in the k-1 pixels: no bias.
    def h_rest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return pixels_from_motion(np.eye(3)[None], np.zeros((1, 3)), rig.triangulate(a, b), rig)[0]

    np.testing.assert_allclose(previous_pixel_bias(h_rest, uvl, uvr, sigma), 0.0, atol=1e-9)
    # Below 6 sigma of disparity the expansion does not hold: no correction.
    assert not np.any(previous_pixel_bias(h_prev, uvl, uvr, 10.0))


def test_features_new_at_k_minus_1_pass_the_disparity_gate_at_twice_the_threshold() -> None:
    # No k-2 pixels (the first pair, or frames seconds apart): the k-1 disparity decides, at
    # twice the threshold (0.3 px noise: 12 x 0.3 = 3.6 px, so 7.2 px); a track seen at k-2
    # is gated on its k-2 disparity as before.
    from svains.frontend.types import StereoTracks
    from svains.navigation.vision_pixels import NEW_FEATURE_DISPARITY_FACTOR

    tf = two_frames(RIG, DT_S, np.zeros(3), np.zeros(3), n_features=60)
    upd = updater_for("3d", _dataset(tf), VisionOptions(shared_pixels=False))
    d_min = upd._min_disparity_px
    assert d_min == pytest.approx(3.6) and NEW_FEATURE_DISPARITY_FACTOR == 2.0

    def tracks(t_prev: int, t: int, ids: list[int], disp: list[float]) -> StereoTracks:
        n = len(ids)
        uvl = np.column_stack([np.full(n, 300.0), np.full(n, 200.0)])
        uvr = uvl - np.column_stack([np.asarray(disp), np.zeros(n)])
        return StereoTracks(t_prev, t, np.asarray(ids, np.int64), uvl, uvr, uvl, uvr,
                            np.ones((n, 3)), np.ones(n, bool), None)  # fmt: skip

    first = upd._near(tracks(0, 1, [1, 2, 3], [5.0, 8.0, 20.0]))
    np.testing.assert_array_equal(first, [False, True, True])
    # Next pair: tracks 1-3 were seen at k-2 (their disparities above); 4 is new at k-1.
    nxt = upd._near(tracks(1, 2, [1, 2, 3, 4], [50.0, 50.0, 50.0, 5.0]))
    np.testing.assert_array_equal(nxt, [True, True, True, False])
    nxt = upd._near(tracks(2, 3, [1, 4, 5], [2.0, 2.0, 7.3]))
    # 1 and 4 are judged on their k-2 disparities (50 and 5 px), 5 is new (7.3 >= 7.2)
    np.testing.assert_array_equal(nxt, [True, True, True])


@pytest.mark.parametrize(("two_view", "fill", "n_fused"),
                         [(True, True, 40), (True, False, 30), (False, True, 30), (True, None, 40)])
def test_two_view_frames_fill_up_with_features_below_the_disparity_gate(
    two_view: bool, fill: bool | None, n_fused: int
) -> None:
    # All 60 features are new at k-1, so the gate is twice min_disparity_px: set at their median
    # disparity, 30 pass it. A two-view frame (the point estimated in inverse depth from its 8
    # pixels) fills up to max_features (40) with the 10 far ones evenly spread, the near ones
    # first (``two_view_fill_far``, on by default: ``fill`` None); the paper's one-view model
    # keeps the gate.
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    disp = tf.uv_left_prev[:, 0] - tf.uv_right_prev[:, 0]
    gate = float(np.median(disp))
    opts = VisionOptions(min_disparity_px=gate / 2, max_features=40, shared_pixels=False,
                         egomotion_fallback=False)  # fmt: skip
    if fill is not None:
        opts = replace(opts, two_view_fill_far=fill)
    upd = updater_for("3d", _dataset(tf), opts)
    ukf = _ukf(tf.x_km1, np.zeros(3))
    upd.after_frame(FrameContext(ukf, PAPER, T0, None, None, [], None))  # type: ignore[arg-type]
    x = ukf.x.copy()
    x[:13] = tf.x_k
    P = ukf.P.copy()
    P[0:3, 0:3] += 1e-4 * np.eye(3)
    ukf.resize(ukf.manifold, x, P)
    ctx = FrameContext(ukf, PAPER, T0 + int(DT_S * 1e9), T0, None, [], None,  # type: ignore[arg-type]
                       two_view=two_view)  # fmt: skip
    stats = upd.update(ctx)
    assert stats is not None and stats.accepted
    assert upd._fused is not None
    fused = upd._fused[1]
    assert fused.size == n_fused
    near = np.flatnonzero(disp >= gate)
    assert near.size == 30 and np.isin(near, fused).all()


def _clone_update_with_position_error(
    tf: TwoFrames, opts: VisionOptions, error_m: float, motion_std_m: float,
    method: str = "3d", gate: float | None = None,
) -> tuple[Any, UKF, Any, np.ndarray]:
    """A ``method`` clone update of ``tf``'s frame k gated at ``gate`` (None: ungated): the k-1
    pose cloned at the truth, the state at k true but for ``error_m`` along x with
    ``motion_std_m`` more position std per axis. Returns the update's stats, the filter, the
    updater and the prior covariance."""
    upd = updater_for(method, _dataset(tf), opts)
    ukf = _ukf(tf.x_km1, np.zeros(3))
    upd.after_frame(FrameContext(ukf, PAPER, T0, None, None, [], None))  # type: ignore[arg-type]
    x = ukf.x.copy()
    x[:13] = tf.x_k
    x[0] += error_m
    P = ukf.P.copy()
    P[0:3, 0:3] += motion_std_m**2 * np.eye(3)
    ukf.resize(ukf.manifold, x, P)
    ctx = FrameContext(ukf, PAPER, T0 + int(DT_S * 1e9), T0, gate, [], None)  # type: ignore[arg-type]
    return upd.update(ctx), ukf, upd, P


def test_a_frame_the_prior_cannot_explain_fuses_its_egomotion_instead() -> None:
    # A 0.5 m position error against a 1 cm prior: every feature fails its gate and the frame
    # is refused, unless its egomotion is fused instead (``vision.egomotion_fallback``).
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)

    def run(fallback: bool) -> tuple[object, UKF, object]:
        # the motion since the clone: known to 1 cm
        opts = VisionOptions(egomotion_fallback=fallback)
        return _clone_update_with_position_error(tf, opts, 0.5, 0.01)[:3]

    stats, ukf, upd = run(True)
    assert stats is not None and stats.accepted and stats.name == "vision_egomotion"
    assert upd.summary()["frames_egomotion"] == 1
    # Pulled towards the truth (0.41 m left: the 1 cm prior against lc's inflated covariance).
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 0.45
    stats, ukf, upd = run(False)
    assert stats is not None and not stats.accepted
    assert upd.summary()["frames_rejected"] == 1 and upd.summary()["frames_gated"] == 1


def test_a_frame_with_too_few_features_for_the_pixels_fuses_its_egomotion() -> None:
    # Every feature below the disparity gate (min_disparity_px far above the scene's): too few
    # for the pixel model, yet the frame still links to k-1 through its egomotion, which uses
    # every tracked feature (issue 22: simulated V1_02 flight at 0.5 Hz, 3d 4.80 -> 2.56 m).
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)

    def run(fallback: bool) -> tuple[object, UKF, object]:
        # the motion since the clone: known to 30 cm
        opts = VisionOptions(egomotion_fallback=fallback, min_disparity_px=1e4)
        return _clone_update_with_position_error(tf, opts, 0.3, 0.3)[:3]

    stats, ukf, upd = run(True)
    assert stats is not None and stats.accepted and stats.name == "vision_egomotion"
    summary = upd.summary()
    assert summary["frames_egomotion"] == 1 and summary["frames_without_tracks"] == 0
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 0.1
    stats, ukf, upd = run(False)
    assert stats is None and upd.summary()["frames_without_tracks"] == 1
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) > 0.29


def _clone_frame(opts: VisionOptions, err_m: float) -> tuple[float, float, float]:
    """One clone update of ``opts`` with the state at k moved by ``err_m`` (m, variance to
    match): (position error before, after, trace of the posterior variance of the position
    relative to the clone)."""
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    upd = updater_for("3d", _dataset(tf), opts)
    ukf = _ukf(tf.x_km1, np.zeros(3))
    upd.after_frame(FrameContext(ukf, PAPER, T0, None, None, [], None))  # type: ignore[arg-type]
    x = ukf.x.copy()
    x[:13] = tf.x_k
    d = err_m * np.array([0.8, -0.5, 0.3])
    x[0:3] += d
    P = ukf.P.copy()
    P[0:3, 0:3] += err_m**2 * np.eye(3)
    ukf.resize(ukf.manifold, x, P)
    stats = upd.update(_ctx(ukf))
    assert stats is not None and stats.accepted
    after = float(np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]))
    # The frame measures the motion from the clone: the variance of p_k - p_clone.
    c = ukf.manifold.tangent(0).start  # type: ignore[attr-defined]
    A = np.zeros((3, ukf.P.shape[0]))
    A[:, 0:3], A[:, c:c + 3] = np.eye(3), -np.eye(3)
    return float(np.linalg.norm(d)), after, float(np.trace(A @ ukf.P @ A.T))


def test_shared_pixels_fuse_every_feature_by_two_view_at_twice_the_variance() -> None:
    """``shared_pixels`` (opt-in) shares each pixel between its two frame pairs: every frame
    two-view, no disparity gate, no single-use filter, each pair's pixels at twice their
    variance, so the fused information is half the single-use two-view frame's."""
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    SHARED = VisionOptions(shared_pixels=True)
    shared = updater_for("3d", _dataset(tf), SHARED)
    assert shared.shared and shared.two_view and shared._min_disparity_px == 0.0
    assert shared.summary()["shared_pixels"] is True
    single = updater_for("3d", _dataset(tf), VisionOptions())  # the default
    assert not single.shared and not single.two_view and single._min_disparity_px > 0.0
    assert single.summary()["shared_pixels"] is False
    # Each pulls a 5 cm error towards the truth; the shared frame fuses half the information.
    before, after_shared, var_shared = _clone_frame(SHARED, 0.05)
    _, after_single, var_single = _clone_frame(VisionOptions(two_view=True, min_disparity_px=0.0),
                                               0.05)  # fmt: skip
    assert after_shared < 0.5 * before and after_single < 0.5 * before
    assert 1.6 < var_shared / var_single < 2.4, (var_shared, var_single)


def test_shared_pixels_are_opt_in_and_need_clones() -> None:
    assert not VisionOptions().shared_pixels
    # Without clones (another motion model) nothing is shared, whatever the option says.
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    opts = VisionOptions(rotation="imu", shared_pixels=True)
    assert not updater_for("3d", _dataset(tf), opts).shared


def test_correlated_pixels_are_opt_in_need_clones_and_a_known_pixel_noise() -> None:
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    assert not VisionOptions().correlated_pixels
    assert not updater_for("3d", _dataset(tf), VisionOptions()).correlated
    upd = updater_for("3d", _dataset(tf), VisionOptions(correlated_pixels=True))
    assert upd.correlated and not upd.shared  # recorded features: their noise is known
    assert upd.summary()["correlated_pixels"] is True
    imu = VisionOptions(rotation="imu", correlated_pixels=True)
    assert not updater_for("3d", _dataset(tf), imu).correlated  # no clones
    with pytest.raises(ConfigError, match=r"vision\.shared_pixels and vision\.correlated_pixels "
                       r"are two ways of fusing a pixel in both frame pairs: choose one"):
        VisionOptions(shared_pixels=True, correlated_pixels=True)


def test_short_frames_fuse_more_features() -> None:
    opts = VisionOptions()  # 120, 300 within 1 s
    assert opts.features_for_gap(0.2) == 300 and opts.features_for_gap(1.0) == 300
    assert opts.features_for_gap(1.01) == 120
    assert VisionOptions(max_features=None).features_for_gap(0.2) is None
    assert VisionOptions(max_features_short=None).features_for_gap(0.2) is None
    assert VisionOptions(max_features_short=50).features_for_gap(0.2) == 120  # the larger
    assert VisionOptions(short_gap_s=None).features_for_gap(0.01) == 120
    with pytest.raises(ConfigError, match=r"vision\.short_gap_s must be >= 0 s or null, got -1"):
        VisionOptions(short_gap_s=-1.0)
    with pytest.raises(ConfigError, match=r"vision\.max_features_short must be >= 1 or null"):
        VisionOptions(max_features_short=0)


def test_lc_refines_the_egomotion_of_short_recorded_frames_on_request() -> None:
    assert VisionOptions().bundle_max_gap_for("lc") is None  # opt-in
    opts = VisionOptions(lc_bundle_short=True)
    assert opts.bundle_max_gap_for("lc") == 1.0
    assert opts.bundle_max_gap_for("3d") is None and opts.bundle_max_gap_for("vo") is None
    assert VisionOptions(lc_bundle_short=True, egomotion_bundle=False).bundle_max_gap_for(
        "lc") is None
    assert VisionOptions(lc_bundle_short=True, short_gap_s=None).bundle_max_gap_for("lc") is None


def _lc_update_with_position_error(
    tf: TwoFrames, opts: VisionOptions, error_m: float, motion_std_m: float,
    gate: float | None = 0.999,
) -> tuple[Any, UKF, Any, np.ndarray]:
    """``_clone_update_with_position_error`` for ``lc``, gated at 0.999 unless told."""
    return _clone_update_with_position_error(tf, opts, error_m, motion_std_m, "lc", gate)


def test_lc_egomotion_just_above_the_gate_is_fused_at_an_inflated_covariance() -> None:
    """``vision.lc_inflate_max``: an egomotion whose NIS is above the gate but within the limit
    is fused with the motion covariance and its own scaled by NIS / gate (the ungated update's
    mean, its NIS on the gate, the posterior wider); far above the limit, or with the option
    off, it is refused and the state is left as it was."""
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    off = VisionOptions(lc_inflate_max=None)
    refused, ukf, upd, P = _lc_update_with_position_error(tf, off, 0.15, 0.01)
    assert refused is not None and not refused.accepted
    assert 1.2 * refused.gate < refused.nis < 4.0 * refused.gate  # 22.5 < NIS < 90
    np.testing.assert_array_equal(ukf.P, P)
    assert upd.summary()["frames_rejected"] == 1 and upd.summary()["frames_inflated"] == 0

    stats, ukf, upd, _ = _lc_update_with_position_error(tf, VisionOptions(), 0.15, 0.01)
    assert stats is not None and stats.accepted
    assert stats.nis == pytest.approx(stats.gate, rel=1e-3)
    assert upd.summary()["frames_inflated"] == 1 and upd.summary()["frames_fused"] == 1
    _, ungated, _, _ = _lc_update_with_position_error(tf, off, 0.15, 0.01, gate=None)
    err = np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3])
    # Pulled in as far as the plain update would (a 1 cm prior against RANSAC x30).
    # (to 0.1 %: the angular-rate block of this state is not scaled)
    assert err < 0.13 and err == pytest.approx(
        np.linalg.norm(ungated.x[0:3] - tf.x_k[0:3]), rel=1e-3)
    ratio = np.diag(ukf.P)[0:3] / np.diag(ungated.P)[0:3]
    np.testing.assert_allclose(ratio, refused.nis / refused.gate, rtol=1e-3)

    far, ukf_far, upd_far, P_far = _lc_update_with_position_error(tf, VisionOptions(), 1.0, 0.01)
    assert far is not None and not far.accepted and far.nis > 4.0 * far.gate
    np.testing.assert_array_equal(ukf_far.P, P_far)
    assert upd_far.summary()["frames_inflated"] == 0


def test_a_3d_fallback_egomotion_just_above_the_gate_is_fused_at_an_inflated_covariance(
) -> None:
    # A 15 cm error against a 1 cm prior: every feature fails its gate, and the frame's
    # egomotion lands just above its own gate. ``lc_inflate_max`` governs the tc/3d fallback
    # too (the fault bench's gyro step, seed 4: the frame 1 s after the step was refused and
    # the bias alarm came 7 s late).
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    refused, ukf, upd, P = _clone_update_with_position_error(
        tf, VisionOptions(lc_inflate_max=None), 0.15, 0.01, "3d", 0.999)
    assert refused is not None and not refused.accepted and refused.name == "vision_egomotion"
    assert refused.gate < refused.nis < 4.0 * refused.gate
    np.testing.assert_array_equal(ukf.P, P)
    assert upd.summary()["frames_inflated"] == 0 and upd.summary()["frames_egomotion"] == 0
    stats, ukf, upd, _ = _clone_update_with_position_error(tf, VisionOptions(), 0.15, 0.01,
                                                           "3d", 0.999)  # fmt: skip
    assert stats is not None and stats.accepted and stats.name == "vision_egomotion"
    assert stats.nis == pytest.approx(stats.gate, rel=1e-3)
    summary = upd.summary()
    assert summary["frames_inflated"] == 1 and summary["frames_egomotion"] == 1
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 0.13


def test_lc_inflate_max_below_one_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"vision.lc_inflate_max must be >= 1 .*got 0.5"):
        VisionOptions(lc_inflate_max=0.5)


def test_a_two_view_frame_over_a_wide_prior_is_linearised_at_its_egomotion() -> None:
    # The prior 0.37 m off (0.32 m std per axis): points refined at that motion carried its
    # error into the null spaces, and the update moved the state away (0.37 -> 0.60 m). The
    # frame's own egomotion fits the pixels better, so the points are refined there.
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    stats, ukf, upd, _ = _clone_update_with_position_error(tf, VisionOptions(two_view=True),
                                                           0.37, 0.1**0.5)  # fmt: skip
    assert stats is not None and stats.accepted and stats.name == "vision_3d"
    assert upd.summary()["frames_linearised_at_egomotion"] == 1
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 0.02
    # A prior that already fits the pixels needs no egomotion.
    _, ukf, upd, _ = _clone_update_with_position_error(tf, VisionOptions(two_view=True),
                                                       0.0, 0.05)  # fmt: skip
    assert upd.summary()["frames_linearised_at_egomotion"] == 0
    assert np.linalg.norm(ukf.x[0:3] - tf.x_k[0:3]) < 1e-3


def test_instrument_pixels_are_the_k2_point_moved_by_the_last_motion() -> None:
    """``vision.instrument_points``: the sigma-point spread is computed from each feature's
    k-2 stereo point moved by the last update's mean motion and projected at k-1 (noise-free
    here: the true k-1 pixels), the k-1 pixels where a feature has no k-2 pixels; none where
    the k-2 frame or the motion is not the one just before."""
    from svains.frontend.types import StereoTracks
    from svains.geometry.rotation import so3_exp
    from svains.models.vision_3d import move_points
    from svains.models.vision_common import project_stereo

    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=20)
    m = len(tf.p_Ckm1_F)
    t_km2, t_km1, t_k = T0 - int(DT_S * 1e9), T0, T0 + int(DT_S * 1e9)
    R, r = so3_exp(np.array([0.01, -0.02, 0.03])), np.array([0.05, -0.02, 0.3])
    p_km2 = (tf.p_Ckm1_F + r) @ R  # p_km1 = R p_km2 - r
    np.testing.assert_allclose(move_points(R[None], r[None], p_km2)[0], tf.p_Ckm1_F, atol=1e-9)
    uv_km2 = project_stereo(p_km2, RIG).reshape(-1, 4)
    ids = np.arange(m, dtype=np.int64)
    e = np.zeros((m, 2))
    tr = StereoTracks(t_km1, t_k, ids, tf.uv_left_prev + 0.7, tf.uv_right_prev + 0.7, e, e,
                      np.zeros((m, 3)), np.ones(m, bool), None)  # fmt: skip
    for instruments in (True, False):
        upd = updater_for("3d", _dataset(tf), VisionOptions(instrument_points=instruments))
        upd._k2 = (t_km2, t_km1, ids[1:], uv_km2[1:, :2], uv_km2[1:, 2:])  # feature 0 new
        upd._motion_before = (t_km2, t_km1, R, r)
        got = upd._instrument_pixels(tr, ids)
        if not instruments:
            assert got is None
            continue
        assert got is not None
        np.testing.assert_allclose(got[0][1:], tf.uv_left_prev[1:], atol=1e-6)
        np.testing.assert_allclose(got[1][1:], tf.uv_right_prev[1:], atol=1e-6)
        np.testing.assert_array_equal(got[0][0], tr.uv_left_prev[0])  # its own k-1 pixels
        upd._motion_before = (t_km2 - 1, t_km1, R, r)  # a motion from another frame
        assert upd._instrument_pixels(tr, ids) is None
