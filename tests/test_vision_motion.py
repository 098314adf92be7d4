"""The front end's IMU motion prior (``navigation.vision_motion``) and the IMU increment window."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _vision_truth import TwoFrames, imu_samples, make_rig, two_frames
from svains.datasets.types import CameraCalib, Dataset, FeatureStream, ImuCalib, ImuStream
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.rotation import quat_to_rotmat, so3_log
from svains.models.manifold import NavManifold
from svains.models.state import PAPER, V
from svains.models.vision_imu import imu_increment
from svains.models.vision_lc import egomotion_from_state_pair
from svains.navigation.base import FrameContext
from svains.navigation.options import VisionOptions
from svains.navigation.vision_motion import MotionPriorOptions, imu_motion_prior
from svains.navigation.vision_pixels import PixelUpdater
from svains.navigation.vision_sources import ImageFrames
from svains.replay.replay import history_from_dataset, rig_from_dataset

RIG = make_rig()
DT_S = 0.1
OMEGA_B = np.array([0.3, -0.2, 0.5])
A_W = np.array([0.4, -0.3, 0.2])
G_W = np.array([0.0, 0.0, -9.81])
T0 = 5_000_000_000
T1 = T0 + int(DT_S * 1e9)


def _ukf(x: np.ndarray, vel_std: float) -> UKF:
    P = np.diag(np.r_[np.full(3, 1e-4), np.full(3, vel_std**2), np.full(3, 1e-8), np.full(3, 1e-8)])
    return UKF(NavManifold(PAPER), MerweScaledSigmaPoints(12), x, P)


def test_prior_is_the_true_camera_motion_with_the_velocity_spread() -> None:
    tf = two_frames(RIG, DT_S, OMEGA_B, A_W)
    t_ns, gyro, accel = imu_samples(tf, OMEGA_B, A_W, G_W)
    inc = imu_increment(t_ns, gyro, accel, 0, round(DT_S * 1e9), G_W)
    R_true, p_true = egomotion_from_state_pair(
        tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]), tf.x_k[:3], RIG
    )
    ukf = _ukf(tf.x_k, vel_std=0.2)
    X, _ = ukf.sigma_points()
    bare = MotionPriorOptions(inflation=1.0, min_std=(0.0, 0.0), rel_std=0.0)
    prior = imu_motion_prior(X, ukf.points.Wm, ukf.points.Wc, ukf.x, DT_S, RIG, inc, None, bare)
    assert np.linalg.norm(so3_log(R_true.T @ prior.R_Ck_Ckm1)) < 1e-5
    np.testing.assert_allclose(prior.p_Ck_Ckm1, p_true, atol=1e-5)
    # A velocity error δv moves the camera by Δt δv: std 0.2 m/s * 0.1 s per axis.
    std = np.sqrt(np.diag(prior.cov))
    np.testing.assert_allclose(std[3:], 0.02, rtol=0.05)
    assert np.all(std[:3] < 1e-3)
    # Inflation scales the variance, floors and IMU noise only ever add.
    wide = imu_motion_prior(
        X, ukf.points.Wm, ukf.points.Wc, ukf.x, DT_S, RIG, inc, (0.01, 0.1),
        MotionPriorOptions(inflation=4.0, min_std=(0.05, 0.0), rel_std=0.0),
    )
    std_w = np.sqrt(np.diag(wide.cov))
    np.testing.assert_allclose(std_w[:3], 0.05)  # floor
    np.testing.assert_allclose(std_w[3:], 2.0 * np.sqrt(0.02**2 + 0.1**2 * DT_S**3 / 3), rtol=0.05)
    assert np.all(np.linalg.eigvalsh(wide.cov) > 0)


def test_imu_increment_window_between_samples_is_exact_for_a_linear_rate() -> None:
    # ω(t) = (a + b t) n about a fixed axis: the midpoint rule and the linear end-point
    # interpolation are exact, so ΔR = Exp(n ∫ω) for any window, on or between samples.
    n = np.array([1.0, 2.0, -2.0]) / 3.0
    t_ns = np.arange(0, 1_000_000_001, 5_000_000, dtype=np.int64)
    t = t_ns * 1e-9
    gyro = (0.4 + 1.5 * t)[:, None] * n
    accel = np.zeros_like(gyro)
    for t0, t1 in ((100_000_000, 300_000_000), (101_234_567, 298_765_432), (2_500_000, 7_500_000)):
        inc = imu_increment(t_ns, gyro, accel, t0, t1, G_W)
        a, b = t0 * 1e-9, t1 * 1e-9
        angle = 0.4 * (b - a) + 0.75 * (b * b - a * a)
        np.testing.assert_allclose(so3_log(inc.dR_Bkm1_Bk), angle * n, atol=1e-12)


# ---- the updater hands the prior to an image source ------------------------------------------
class _StubImages(ImageFrames):
    """An image source with fixed tracks (no images, no front end): records the priors."""

    def __init__(self, tracks: StereoTracks, t_ref: int | None) -> None:  # no super(): no images
        self.rig = RIG
        self.pixel_noise_std = 0.3
        self.status_counts: dict[str, int] = {}
        self._tracks = tracks
        self._t_ref = t_ref
        self.priors: list[Egomotion | None] = []

    def reference_time_ns(self) -> int | None:
        return self._t_ref

    def tracks_at(self, t_ns: int, motion_prior: Egomotion | None = None) -> StereoTracks | None:
        self.priors.append(motion_prior)
        return self._tracks


def _dataset_and_tracks() -> tuple[Dataset, StereoTracks, TwoFrames]:
    tf = two_frames(RIG, DT_S, OMEGA_B, A_W, n_features=40)
    t_rel, gyro, accel = imu_samples(tf, OMEGA_B, A_W, G_W)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = RIG.R_B_C, RIG.p_B_C
    T1_ = T.copy()
    T1_[:3, 3] = RIG.p_B_C + RIG.R_B_C @ np.array([RIG.baseline, 0.0, 0.0])
    intr = np.array([RIG.f, RIG.f, RIG.cu, RIG.cv])
    cams = [CameraCalib(nm, TT, 20.0, (RIG.width, RIG.height), intr, "radtan", np.zeros(4))
            for nm, TT in (("cam0", T), ("cam1", T1_))]
    m = len(tf.p_Ckm1_F)
    fs = FeatureStream(
        t_ns=np.repeat(np.array([T0, T1], np.int64), m), track_id=np.tile(np.arange(m), 2),
        uv_left=np.vstack([tf.uv_left_prev, tf.uv_left]),
        uv_right=np.vstack([tf.uv_right_prev, tf.uv_right]), pixel_noise_std=0.3,
    )
    ds = Dataset(
        root=Path("memory"), name="two-frames", cam0=cams[0], cam1=cams[1], features=fs,
        imu=ImuStream(t_rel + T0, gyro, accel),
        imu_calib=ImuCalib(np.eye(4), 200.0, 1e-3, 1e-5, 1e-2, 1e-4), gravity_W=G_W,
    )
    tracks = StereoTracks(
        t_prev_ns=T0, t_ns=T1, track_id=np.arange(m), uv_left_prev=tf.uv_left_prev,
        uv_right_prev=tf.uv_right_prev, uv_left=tf.uv_left, uv_right=tf.uv_right,
        p_Ckm1_F=RIG.triangulate(tf.uv_left_prev, tf.uv_right_prev), inlier=np.ones(m, bool),
        egomotion=None,
    )
    return ds, tracks, tf


@pytest.mark.parametrize(
    ("enabled", "after_s", "t_ref", "given"),
    [
        (True, 1.0, T0, True),  # on every frame
        (False, 1.0, T0, False),  # the default: frames 0.1 s apart get none
        (False, DT_S, T0, True),  # frames that far apart get it
        (False, 0.15, T0, False),
        (False, None, T0, False),  # never
        (True, 1.0, None, False),  # no reference frame yet
    ],
)
def test_pixel_updater_passes_the_prior_over_the_reference_interval(
    enabled: bool, after_s: float | None, t_ref: int | None, given: bool
) -> None:
    ds, tracks, tf = _dataset_and_tracks()
    opts = VisionOptions(source="features", rotation="imu", motion_prior=enabled,
                         motion_prior_after_s=after_s)  # fmt: skip
    src = _StubImages(tracks, t_ref)
    upd = PixelUpdater("3d", opts, src, history_from_dataset(ds), rig_from_dataset(ds))
    x0 = tf.x_k.copy()
    dv = np.array([0.2, -0.1, 0.1])
    x0[V] += dv
    ukf = _ukf(x0, vel_std=0.3)
    stats = upd.update(FrameContext(ukf, PAPER, T1, T0, None, [], None))  # type: ignore[arg-type]
    assert stats is not None and stats.accepted
    assert np.linalg.norm(ukf.x[V] - tf.x_k[V]) < 0.1  # prior error 0.245 m/s
    prior = src.priors[0]
    if not given:
        assert prior is None
        return
    assert isinstance(prior, Egomotion)
    R_true, p_true = egomotion_from_state_pair(
        tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]), tf.x_k[:3], RIG
    )
    # Exact attitude and IMU: the rotation is right; the state's velocity error δv moves the
    # predicted camera by Δt δv (camera components), well inside the generous covariance.
    assert np.linalg.norm(so3_log(R_true.T @ prior.R_Ck_Ckm1)) < 1e-4
    p_err = prior.p_Ck_Ckm1 - p_true
    np.testing.assert_allclose(p_err, -DT_S * (RIG.R_B_C.T @ quat_to_rotmat(x0[6:10]).T @ dv),
                               atol=1e-4)
    std = np.sqrt(np.diag(prior.cov))
    assert np.all(std[3:] >= 5e-3) and np.all(np.abs(p_err) < 3 * std[3:])
    assert np.all(np.linalg.eigvalsh(prior.cov) > 0)
