"""``StereoFrontend`` end to end: real KITTI frames, synthetic scenes and every degenerate input."""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.frontend.pipeline import FrontendOptions, StereoFrontend
from svains.frontend.reacquire import ReacquireOptions
from svains.frontend.types import Egomotion, StereoTracks
from svains.frontend.vo_chain import relative_motion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_log

# Ideal synthetic rig: a textured fronto-parallel plane at 4 m gives 10 px of disparity.
RIG = RectifiedStereo(400.0, 160.0, 120.0, 0.1, np.eye(3), np.zeros(3), 320, 240)
DISP = 10


def _texture(seed: int, shape: tuple[int, int] = (240, 360)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.random((shape[0] // 4, shape[1] // 4)).astype(np.float32)
    big = cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return np.clip(40 + 180 * big, 0, 255).astype(np.uint8)


_EXPOSURES = itertools.count()


def _pair(tex: np.ndarray, shift_px: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Left/right views of the plane; ``shift_px`` moves the plane (object) sideways. Each call
    is a new exposure: the lowest bit of one corner pixel alternates, as a real sensor's noise
    makes every frame differ (an exact repeat is a frozen camera, dropped)."""
    x0 = 20 + shift_px
    left = np.ascontiguousarray(tex[:, x0 : x0 + 320])
    right = tex[:, x0 + DISP : x0 + DISP + 320]  # right image sees the plane DISP px further left
    left[0, 0] = (int(left[0, 0]) & 0xFE) | (next(_EXPOSURES) & 1)
    return left, np.ascontiguousarray(right)


def _frontend(**kw: object) -> StereoFrontend:
    return StereoFrontend.from_rig(RIG, FrontendOptions(**kw))  # type: ignore[arg-type]


def _static(t: StereoTracks | None) -> float:
    assert t is not None and t.egomotion is not None
    return float(np.linalg.norm(t.egomotion.p_Ck_Ckm1))


def test_static_synthetic_plane_depth_and_zero_motion() -> None:
    fe = _frontend()
    tex = _texture(0)
    assert fe.process(0, *_pair(tex)) is None  # first frame: no measurement
    tr = fe.process(1, *_pair(tex))
    assert isinstance(tr, StereoTracks) and tr.egomotion is not None
    assert tr.inlier.sum() > 100
    z = tr.p_Ckm1_F[tr.inlier, 2]  # eq. 10 depth of the plane
    assert np.median(np.abs(z - 4.0)) < 0.01
    # A static camera cannot expose a wrong depth by reprojection: a few sub-pixel disparity
    # errors survive; nearly all depths must still be within 2 %.
    assert np.mean(np.abs(z - 4.0) < 0.08) > 0.97
    assert _static(tr) < 1e-3
    assert tr.t_prev_ns == 0 and tr.t_ns == 1


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((240, 320), np.uint8),  # black
        np.full((240, 320), 255, np.uint8),  # saturated
        np.full((240, 320), 128, np.uint8),  # textureless
        None,  # dropped
        np.zeros((10, 10), np.uint8),  # wrong size (corrupt)
        np.full((240, 320), np.nan),  # garbage values
    ],
    ids=["black", "saturated", "textureless", "dropped", "wrong_size", "nan"],
)
def test_degenerate_frame_gives_no_motion_and_recovers(bad: np.ndarray | None) -> None:
    fe = _frontend()
    tex = _texture(1)
    fe.process(0, *_pair(tex))
    fe.process(1, *_pair(tex))
    left_ok, right_ok = _pair(tex)
    out = fe.process(2, bad, right_ok)
    assert out is not None and out.egomotion is None and not out.has_motion
    assert out.inlier.size == 0 and out.t_ns == 2 and out.t_prev_ns == 1
    assert fe.stats.status in ("textureless", "dropped")
    nxt = fe.process(3, left_ok, right_ok)  # next good frame tracks against frame 1
    assert nxt is not None and nxt.has_motion and nxt.t_prev_ns == 1
    assert nxt.inlier.sum() > 100 and _static(nxt) < 1e-3


def test_a_pair_of_another_size_is_dropped_with_a_warning_naming_both_sizes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    fe = _frontend()
    tex = _texture(1)
    fe.process(0, *_pair(tex))
    small = np.zeros((120, 160), np.uint8)  # a driver that switched to 2x2 binning
    with caplog.at_level("INFO", logger="svains.frontend.pipeline"):
        for k in range(1, 6):
            fe.process(k, small, small)
        fe.process(6, None, None)  # a frame the caller lost: no warning
    warned = [r for r in caplog.records if r.levelname == "WARNING"]
    # the first three, then one per hundred
    assert len(warned) == 3 and "stereo pair dropped (3 so far)" in warned[-1].getMessage()
    assert "image is 160x120 px, the calibration's 320x240" in warned[0].getMessage()
    assert fe.stats.status == "dropped"


def test_degenerate_first_frames_never_raise() -> None:
    fe = _frontend()
    assert fe.process(0, None, None) is None
    assert fe.process(1, np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8)) is None
    tex = _texture(2)
    assert fe.process(2, *_pair(tex)) is None  # first good frame
    assert fe.process(3, *_pair(tex)).has_motion  # type: ignore[union-attr]


def test_all_features_on_moving_object_rejected_with_prior() -> None:
    """The whole view is an object sliding sideways while the (IMU) prior says the camera is
    still: no motion measurement, every feature an outlier, recovery once the object is gone."""
    fe = _frontend()
    tex = _texture(3)
    still = Egomotion(np.eye(3), np.zeros(3), np.diag([1e-6] * 3 + [1e-6] * 3))
    fe.process(0, *_pair(tex), motion_prior=still)
    assert fe.process(1, *_pair(tex), motion_prior=still).has_motion  # type: ignore[union-attr]
    moved = fe.process(2, *_pair(tex, shift_px=6), motion_prior=still)
    assert moved is not None and moved.egomotion is None
    assert moved.inlier.size > 100 and not moved.inlier.any()
    assert fe.stats.status == "contradicts_prior"
    back = fe.process(3, *_pair(tex), motion_prior=still)
    assert back is not None and back.has_motion and back.t_prev_ns == 1
    assert _static(back) < 1e-3


def test_moving_object_without_prior_is_measured_as_motion() -> None:
    """Documented limitation: without a prior a view-filling rigid object is indistinguishable
    from egomotion; the estimate then equals the object's apparent motion (7.5 cm here)."""
    fe = _frontend()
    tex = _texture(4)
    fe.process(0, *_pair(tex))
    tr = fe.process(1, *_pair(tex, shift_px=3))
    assert tr is not None and tr.egomotion is not None
    # Plane moved 3 px left in the image at 4 m: camera apparently moved +x by 3 * 4 / 400 m.
    assert tr.egomotion.p_Ck_Ckm1[0] == pytest.approx(-0.03, abs=2e-3)


def test_kitti_frames_and_black_frame(kitti_a: Path) -> None:
    ds = load_dataset(kitti_a)
    fe = StereoFrontend.from_calibration(ds.cam0, ds.cam1)  # type: ignore[arg-type]
    assert fe.rectifier.identity
    gt = ds.groundtruth
    assert gt is not None

    def T(i: int) -> np.ndarray:
        from svains.geometry.rotation import quat_to_rotmat

        M = np.eye(4)
        M[:3, :3] = quat_to_rotmat(gt.q_W_B_wxyz[i])
        M[:3, 3] = gt.p_W_B[i]
        return M

    imgs = [(ds.left.load(i), ds.right.load(i)) for i in range(3)]  # type: ignore[union-attr]
    assert fe.process(0, *imgs[0]) is None
    tr = fe.process(1, *imgs[1])
    assert tr is not None and tr.egomotion is not None and tr.inlier.sum() >= 100
    R_true, p_true = relative_motion(T(0), T(1))
    assert np.linalg.norm(tr.egomotion.p_Ck_Ckm1 - p_true) < 0.03 * np.linalg.norm(p_true)
    assert np.degrees(np.linalg.norm(so3_log(R_true.T @ tr.egomotion.R_Ck_Ckm1))) < 0.15
    black = fe.process(2, np.zeros_like(imgs[2][0]), imgs[2][1])
    assert black is not None and black.egomotion is None
    tr2 = fe.process(3, *imgs[2])  # frame 2's images, reference still frame 1
    assert tr2 is not None and tr2.has_motion and tr2.t_prev_ns == 1
    R_true, p_true = relative_motion(T(1), T(2))
    assert np.linalg.norm(tr2.egomotion.p_Ck_Ckm1 - p_true) < 0.03 * np.linalg.norm(p_true)  # type: ignore[union-attr]


def test_blocked_corners_are_not_proposed_again_and_keep_no_quota() -> None:
    from svains.frontend.features import DetectorOptions, detect_corners

    img = _texture(5, (240, 320))
    opts = DetectorOptions()
    first = detect_corners(img, np.zeros((0, 2)), opts)
    blocked = first[::5]
    again = detect_corners(img, np.zeros((0, 2)), opts, uv_blocked=blocked)
    d = np.linalg.norm(again[:, None] - blocked[None], axis=2).min(axis=1)
    assert np.all(d >= opts.min_distance_px)  # neither the corner nor a neighbour comes back
    # Blocked places do not count as features: the buckets are refilled from other corners.
    assert again.shape[0] >= 0.9 * first.shape[0]


def test_still_camera_searches_new_corners_only_when_tracks_are_lost() -> None:
    fe = _frontend(redetect_every=4)
    tex = _texture(0)
    left, right = _pair(tex)
    fe.process(0, left, right)
    assert "detect" in fe.stats.timings_ms and fe.stats.new > 100
    n0 = fe.stats.new
    for k in range(1, 4):  # nothing lost: no corner search, the same tracks go on
        tr = fe.process(k, *_pair(tex))
        assert tr is not None and tr.egomotion is not None
        assert "detect" not in fe.stats.timings_ms and fe.stats.new == 0
        assert fe.stats.inliers >= 0.95 * n0
    fe.process(4, *_pair(tex))  # every 4th frame regardless
    assert "detect" in fe.stats.timings_ms
    # Half of the view goes blank: many tracks are lost, so corners are sought. A track that
    # KLT loses counts at once; one that KLT lets drift over the blank half (with the few
    # pyramid levels a still camera gets, KltOptions.adaptive_levels) is lost at the
    # left-right match, and counts on the next frame.
    blank_l, blank_r = left.copy(), right.copy()
    blank_l[:, 160:] = 128
    blank_r[:, 150:] = 128
    tr = fe.process(5, blank_l, blank_r)
    assert fe.stats.status == "ok" and fe.stats.inliers < 0.7 * n0
    assert tr is not None and np.all(tr.uv_left[tr.inlier, 0] < 160 + 6)  # half a KLT window
    searched = "detect" in fe.stats.timings_ms
    blank_l[0, 0] ^= 1  # the next exposure
    fe.process(6, blank_l, blank_r)
    assert searched or "detect" in fe.stats.timings_ms


@pytest.mark.parametrize("retry_levels", [0, 4])
def test_sudden_reversal_is_recovered_by_the_unpredicted_retry(retry_levels: int) -> None:
    """The plane moves 40 px per frame, then reverses: the constant-velocity prediction is 80 px
    off. Without the retry the predicted tracks give no consensus; with it the motion is found.
    (Re-acquisition by descriptors, which would find it too, is off here.)"""
    tex = _texture(3, (240, 700))
    fe = _frontend(retry_levels=retry_levels, reacquire=ReacquireOptions(enabled=False))
    tracks = [fe.process(k, *_pair(tex, s)) for k, s in enumerate([100, 140, 180, 140])]
    for tr in tracks[1:3]:
        assert tr is not None and tr.egomotion is not None
        assert tr.egomotion.p_Ck_Ckm1 == pytest.approx([-0.4, 0.0, 0.0], abs=0.01)
    last = tracks[3]
    assert last is not None
    if retry_levels == 0:
        assert fe.stats.status == "no_consensus" and last.egomotion is None
    else:
        assert fe.stats.status == "ok" and last.egomotion is not None
        assert last.egomotion.p_Ck_Ckm1 == pytest.approx([0.4, 0.0, 0.0], abs=0.01)


def test_sudden_reversal_without_retry_is_recovered_by_descriptors() -> None:
    """The same reversal with the KLT retry off: re-acquisition by descriptors finds it."""
    tex = _texture(3, (240, 700))
    fe = _frontend(retry_levels=0)
    tracks = [fe.process(k, *_pair(tex, s)) for k, s in enumerate([100, 140, 180, 140])]
    last = tracks[3]
    assert fe.stats.status == "ok" and "reacquire" in fe.stats.timings_ms
    assert last is not None and last.egomotion is not None
    assert last.egomotion.p_Ck_Ckm1 == pytest.approx([0.4, 0.0, 0.0], abs=0.01)


def test_small_consensus_among_many_tracks_is_no_measurement() -> None:
    """A motion is measured only if at least ``min_inlier_fraction`` of the matched features
    are RANSAC inliers: the same frame passes just below its inlier fraction, fails just above.
    (Re-acquisition, off here, would start over from new matches on the good rows.)"""
    tex = _texture(0)
    left, right = _pair(tex)
    right_bad = right.copy()
    rows = np.random.default_rng(0).permutation(240)[:60]  # a quarter of the rows mismatched
    right_bad[rows] = np.roll(right_bad[rows], 3, axis=1)

    def run(fraction: float) -> tuple[str, float]:
        fe = _frontend(min_inlier_fraction=fraction, reacquire=ReacquireOptions(enabled=False))
        fe.process(0, left, right)
        fe.process(1, left, right_bad)
        n = fe.stats.tracked
        return fe.stats.status, (fe.stats.inliers / n if n else 0.0)

    status, frac = run(0.0)
    assert status == "ok" and 0.3 < frac < 0.98
    assert run(frac - 0.02)[0] == "ok"
    assert run(frac + 0.02)[0] == "no_consensus"


def test_reference_time_is_the_last_good_frame() -> None:
    fe = _frontend()
    tex = _texture(0)
    assert fe.reference_t_ns is None
    fe.process(10, None, None)  # dropped before any good frame
    assert fe.reference_t_ns is None
    fe.process(20, *_pair(tex))
    assert fe.reference_t_ns == 20
    fe.process(30, np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8))  # black
    assert fe.reference_t_ns == 20  # a degenerate frame does not replace the reference
    fe.process(40, *_pair(tex))
    assert fe.reference_t_ns == 40


def test_klt_levels_follow_the_last_prediction_residual() -> None:
    """``levels_for_residual``: the fewest levels whose reach (2 px doubling per level) covers
    1.5x the residual, all levels for an unknown one; the front end tracks a still plane with
    no level above the base once its prediction proved exact, and with all of them after the
    unpredicted retry (the prediction 80 px off: the plane reverses)."""
    import svains.frontend.pipeline as pipeline
    from svains.frontend.tracking import KltOptions, levels_for_residual

    o = KltOptions()
    got = [levels_for_residual(r, o) for r in (0.0, 1.3, 1.4, 2.6, 2.7, 5.4, 50.0, np.nan)]
    assert got == [0, 0, 1, 1, 2, 3, 3, 3]
    used: list[int | None] = []
    track = pipeline.track_klt

    def spy(*a: object, **k: object) -> object:
        used.append(k.get("max_level"))  # type: ignore[arg-type]
        return track(*a, **k)  # type: ignore[arg-type]

    pipeline.track_klt = spy  # type: ignore[assignment]
    try:
        fe = _frontend(reacquire=ReacquireOptions(enabled=False))
        tex = _texture(3, (240, 700))
        for k, s in enumerate([100, 100, 100, 140, 180, 140, 100]):
            fe.process(k, *_pair(tex, s))
    finally:
        pipeline.track_klt = track  # type: ignore[assignment]
    # Frame 1 is unpredicted (all 3 levels); 2: still, residual unknown yet -> 3; 3: the still
    # prediction was exact -> 0 levels, but the plane jumps 40 px: no consensus, retry with
    # retry_levels (4); 4: no residual after the retry -> 3, and the constant-velocity
    # prediction is exact again; 5: 0 levels, the plane reverses (80 px off): retry (4); 6: 3.
    assert used == [3, 3, 0, 4, 3, 0, 4, 3]
    assert fe.stats.status == "ok"


def test_a_repeated_pair_is_dropped_as_frozen(caplog: pytest.LogCaptureFixture) -> None:
    """A stereo pair equal to the one before to the last grey level (a frozen driver) gives no
    motion and keeps the reference, warned once per run of repeats; a pair that differs by a
    single grey level is a new exposure (a static scene with the sensor's noise)."""
    fe = _frontend()
    tex = _texture(4)
    assert fe.process(0, *_pair(tex, 0)) is None
    moved_left, moved_right = _pair(tex, 3)
    moved = fe.process(1, moved_left, moved_right)
    assert moved is not None and moved.egomotion is not None and fe.stats.status == "ok"
    with caplog.at_level(logging.WARNING, logger="svains.frontend.pipeline"):
        for k in (2, 3, 4):
            frozen = fe.process(k, moved_left, moved_right)  # frame 1's pair, byte for byte
            assert frozen is not None and frozen.egomotion is None and frozen.track_id.size == 0
            assert fe.stats.status == "frozen" and fe.reference_t_ns == 1
    assert caplog.text.count("frozen camera") == 1
    left, right = _pair(tex, 6)
    after = fe.process(5, left, right)  # tracked against frame 1, the last good one
    assert after is not None and after.t_prev_ns == 1 and after.egomotion is not None
    noisy = left.copy()
    noisy[0, 0] ^= 1  # one grey level at one pixel: another exposure
    again = fe.process(6, noisy, right)
    assert fe.stats.status == "ok" and again is not None and again.egomotion is not None
    # a driver that refills one buffer for every frame: each refill is a new frame
    buf_l, buf_r = _pair(tex, 8)
    fe.process(7, buf_l, buf_r)
    buf_l[:], buf_r[:] = _pair(tex, 10)
    refilled = fe.process(8, buf_l, buf_r)
    assert fe.stats.status == "ok" and refilled is not None and refilled.egomotion is not None
