"""``lc`` on a simulated village flight: the model with the true state, and whether the measurement
covariance the updater fuses matches the real egomotion error (issue 6: why lc lost to vo)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from _nav_feed import updater_for
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset
from svains.errors import DatasetError
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.rotation import quat_to_rotmat, so3_exp, so3_log
from svains.models.vision_imu import imu_increment
from svains.models.vision_lc import egomotion_from_state_pair, predict_egomotion_lc
from svains.navigation.options import LC_COV_SCALE, VisionOptions
from svains.navigation.vision import LcUpdater
from svains.replay.groundtruth import interpolate_groundtruth
from svains.sim import SimConfig, simulate


@pytest.fixture(scope="module")
def village(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    """12 s of the village flight, stereo 5 Hz, features0 only (0.5 px noise), seed 3."""
    cfg = SimConfig()
    cfg = replace(cfg, seed=3, duration_s=12.0,
                  camera=replace(cfg.camera, rate_hz=5.0, render_images=False))
    root = simulate(cfg, Path(tmp_path_factory.mktemp("lc_village")))
    return load_dataset(root)


def _frames(ds: Dataset, updater: LcUpdater) -> list[tuple[StereoTracks, np.ndarray, np.ndarray]]:
    """(tracks, true z (6,), true state at k (19,)) for every frame with an egomotion."""
    gt = ds.groundtruth
    assert gt is not None
    out = []
    for t in updater.frame_times:
        tr = updater.source.tracks_at(int(t))
        if tr is None or tr.egomotion is None:
            continue
        inside, p, v, q = interpolate_groundtruth(gt, np.array([tr.t_prev_ns, tr.t_ns]))
        if not inside.all():
            continue
        R = quat_to_rotmat(q)
        R_true, p_true = egomotion_from_state_pair(R[0], p[0], R[1], p[1], updater.rig)
        j = min(np.searchsorted(gt.t_ns, tr.t_ns), len(gt.t_ns) - 1)
        x = np.concatenate([p[1], v[1], q[1], np.zeros(3), gt.bg_B[j], gt.ba_B[j]])
        out.append((tr, np.concatenate([so3_log(R_true), p_true]), x))
    return out


def test_lc_model_with_true_state_matches_true_egomotion(village: Dataset) -> None:
    """With the true state at t_k and the IMU increment (true biases removed), the ``imu`` model
    predicts the true camera motion up to the IMU noise integrated over one frame: no bias in
    any of the 6 numbers (a sign, frame or order error would leave errors of the motion's size,
    ~0.4 m and ~10 mrad)."""
    up = updater_for("lc", village, VisionOptions(source="features", rotation="imu"))
    imu, cal = village.imu, village.imu_calib
    assert imu is not None and cal is not None
    errs = []
    for tr, z_true, x in _frames(village, up):
        inc = imu_increment(imu.t_ns, imu.gyro_B, imu.accel_B, tr.t_prev_ns, tr.t_ns,
                            village.gravity_W, x[13:16], x[16:19])
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        errs.append(z_true - predict_egomotion_lc(x, dt_s, up.rig, "imu", inc))
    e = np.array(errs)
    assert len(e) > 40
    sigma_rot = cal.gyro_noise_density * np.sqrt(0.2)  # white gyro noise over one 0.2 s frame
    rms = np.sqrt(np.mean(e**2, axis=0))
    np.testing.assert_array_less(rms[:3], 1.6 * sigma_rot)
    np.testing.assert_array_less(rms[3:], 0.01)  # m; the motion per frame is ~0.4 m
    np.testing.assert_array_less(np.abs(e.mean(axis=0)), 4.0 * rms / np.sqrt(len(e)) + 1e-6)


def test_lc_measurement_covariance_is_consistent(village: Dataset) -> None:
    """NEES of the true egomotion error against the front end's own covariance (factor 1) and
    against the one the updater fuses (default ``LC_COV_SCALE``).

    The old residual-scaled normal matrix gave 140-200 (6 if consistent). The four-pixel
    covariance (``frontend.egomotion_cov``) gave 18-29 on features0 (seeds 0, 3, 5) before the
    RANSAC refinement settled its selection; on this fixture it is now 6.28. ``LC_COV_SCALE``
    = 30 is chosen for lc's accuracy, not consistency, so the fused covariance is conservative
    (NEES 0.21)."""
    raw = updater_for("lc", village, VisionOptions(source="features", lc_cov_scale=1.0))
    fused = updater_for("lc", village, VisionOptions(source="features", rotation="imu"))
    nees_raw, nees_fused = [], []
    for tr, z_true, _ in _frames(village, raw):
        assert tr.egomotion is not None
        for up, out in ((raw, nees_raw), (fused, nees_fused)):
            z, cov = up.measurement(tr)
            e = np.concatenate([so3_log(so3_exp(z_true[:3]).T @ tr.egomotion.R_Ck_Ckm1),
                                z[3:] - z_true[3:]])
            out.append(e @ np.linalg.solve(cov, e))
    assert len(nees_raw) > 40
    # Measured 2026-12-02: 6.28 over 60 frames (6 dof: consistent; the 95 % band of 60
    # independent draws is 5.15-6.91, consecutive egomotions share pixels): limits 1.3x. The
    # fused covariance is the raw one times LC_COV_SCALE exactly.
    assert 6.28 / 1.3 < np.mean(nees_raw) < 6.28 * 1.3
    np.testing.assert_allclose(np.mean(nees_fused), np.mean(nees_raw) / LC_COV_SCALE, rtol=1e-6)


def test_lc_measurement_scales_and_floors_the_covariance(village: Dataset) -> None:
    up = updater_for("lc", village, VisionOptions(source="features", lc_cov_scale=4.0,
                                          lc_min_std=(0.5, 2.0)))
    tr = next(t for t, _, _ in _frames(village, up))
    assert tr.egomotion is not None
    _, cov = up.measurement(tr)
    np.testing.assert_allclose(np.diag(cov), [0.25] * 3 + [4.0] * 3)  # all floored
    up2 = updater_for("lc", village, VisionOptions(source="features", lc_cov_scale=4.0,
                                           lc_min_std=(0.0, 0.0)))
    _, cov2 = up2.measurement(tr)
    raw = tr.egomotion.cov
    np.testing.assert_allclose(cov2, 2.0 * (raw + raw.T), rtol=1e-12, atol=1e-18)


def test_lc_measurement_without_egomotion_raises(village: Dataset) -> None:
    up = updater_for("lc", village, VisionOptions(source="features"))
    tr = next(t for t, _, _ in _frames(village, up))
    with pytest.raises(DatasetError, match="carry no egomotion"):
        up.measurement(replace(tr, egomotion=None))
    assert isinstance(tr.egomotion, Egomotion)


def test_lc_bundle_short_refines_the_short_frames_only(village: Dataset) -> None:
    """``vision.lc_bundle_short``: the egomotion of recorded frames at most ``short_gap_s`` apart
    is the bundle adjustment's (``TrackOptions.bundle_max_gap_s``), of frames further apart
    RANSAC's; the updater fuses the first at ``LC_COV_SCALE_BUNDLE``."""
    from svains.navigation.options import LC_COV_SCALE_BUNDLE
    from svains.navigation.tracks import TrackBuilder, TrackOptions, frame_slices

    assert village.features is not None and village.cam0 is not None
    up = updater_for("lc", village, VisionOptions(source="features", lc_bundle_short=True))
    fs = village.features
    times, bounds = frame_slices(fs)
    for stride, expected in ((1, "bundle"), (10, "forward")):  # 0.2 s and 2 s apart
        builder = TrackBuilder(up.rig, TrackOptions(egomotion=True, bundle_max_gap_s=1.0))
        kinds = []
        for k in range(0, len(times), stride):
            r = slice(bounds[k], bounds[k + 1])
            tr = builder.add(int(times[k]), fs.track_id[r], fs.uv_left[r], fs.uv_right[r])
            if tr is not None and tr.egomotion is not None:
                kinds.append(tr.egomotion.estimator)
        assert len(kinds) >= 4 and set(kinds) == {expected}, (stride, kinds)
    opts = VisionOptions(lc_bundle_short=True)
    assert opts.lc_scale("bundle") == LC_COV_SCALE_BUNDLE == 2.0
