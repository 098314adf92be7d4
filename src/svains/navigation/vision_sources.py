"""Where the vision updaters get their stereo tracks: pre-tracked features or the front end.

Both sources are fed one frame at a time (``push``) in time order, and give
``tracks_at(t_ns, motion_prior=None) -> StereoTracks | None`` when the estimator reaches the
frame. Pre-tracked features are paired with the previous frame on arrival (``TrackBuilder``);
images wait for the estimator, because the front end's motion prior needs the filter at t_k.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.navigation.outputs import TrackLog
from svains.navigation.relocalise import Keyframe, most_shared
from svains.navigation.tracks import Frame, TrackBuilder, TrackOptions, pair_frames
from svains.sensors.types import CameraCalib

if TYPE_CHECKING:
    from svains.frontend.reacquire import OrbStereo

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
U8 = NDArray[np.uint8]


# Keyframes tried by descriptors for one frame that lost its link (closest views first).
RELOCALISE_TRIES = 5


def pixel_std_px(configured: float | None, source: FeatureFrames | ImageFrames) -> float:
    """The pixels' own noise (px): the configured ``vision.pixel_noise_std``, else the
    source's (recorded features carry theirs; the image front end's is a placeholder), at
    least 0.05 px."""
    std = source.pixel_noise_std if configured is None else configured
    return max(float(std), 0.05)


def rig_from_calibrations(cam0: CameraCalib | None, cam1: CameraCalib | None) -> RectifiedStereo:
    """The rectified pair that ``cam0``/``cam1`` define (``features0`` pixels live in it)."""
    if cam0 is None or cam1 is None:
        raise ConfigError("vision methods need the cam0 and cam1 calibrations")
    from svains.frontend.rectify import StereoRectifier

    return StereoRectifier.from_calibration(cam0, cam1).rig


def stereo_check_summary(source: object) -> dict[str, Any]:
    """``{"stereo_check": {...}}`` of an image source's front end (``frontend.stereo_check``:
    left and right swapped, rows that do not agree), empty for other sources."""
    frontend = getattr(source, "frontend", None)
    if frontend is None or getattr(frontend, "stereo_check", None) is None:
        return {}
    return {"stereo_check": frontend.stereo_check_report().summary()}


def _logged(log: TrackLog, tracks: StereoTracks | None) -> StereoTracks | None:
    """``tracks``, kept in ``log`` (the run's ``tracks.csv``) first."""
    if tracks is not None:
        log.add(tracks.t_ns, tracks.track_id, tracks.uv_left, tracks.inlier)
    return tracks


class FeatureFrames:
    """Tracks from pre-tracked features (``features0`` or an external front end).

    ``pixel_noise_std`` (px): the features' noise, 1 px unless the configuration sets it.
    """

    kind = "features"

    def __init__(self, rig: RectifiedStereo, track_options: TrackOptions) -> None:
        self.rig = rig
        self.pixel_noise_std = 1.0
        self._builder = TrackBuilder(rig, track_options)
        self.track_options = track_options
        self._tracks: dict[int, StereoTracks] = {}
        # Every feature of the frames pushed and not yet asked for, and of the last one asked
        # for (``current``): a relocalisation pairs it with a stored keyframe.
        self._frames: dict[int, Frame] = {}
        self.current: Frame | None = None
        self.track_log = TrackLog()

    def push(self, t_ns: int, track_id: I64, uv_left: F64, uv_right: F64) -> bool:
        """Pair this frame with the previous one; True if it gave tracks (not the first)."""
        tr = self._builder.add(t_ns, track_id, uv_left, uv_right)
        frame = self._builder.last
        assert frame is not None
        self._frames[int(t_ns)] = frame
        if tr is not None:
            self._tracks[int(t_ns)] = tr
        return tr is not None

    def discard(self, t_ns: int) -> None:
        self._tracks.pop(int(t_ns), None)
        self._frames.pop(int(t_ns), None)

    def tracks_at(self, t_ns: int, motion_prior: Egomotion | None = None) -> StereoTracks | None:
        """The tracks ending at ``t_ns`` (``motion_prior`` is not needed here)."""
        t = int(t_ns)
        self.current = self._frames.pop(t, None)
        for old in [s for s in self._frames if s < t]:  # frames never asked for
            del self._frames[old]
        return _logged(self.track_log, self._tracks.pop(t, None))

    def keyframe_features(self, t_ns: int) -> Frame | None:
        """The features of the frame last asked for, if at ``t_ns`` (a keyframe's)."""
        f = self.current
        return f if f is not None and f[0] == int(t_ns) else None

    def relocalisation_tracks(
        self, t_ns: int, keyframes: Sequence[Keyframe], min_features: int
    ) -> tuple[Keyframe, StereoTracks] | None:
        """Tracks to the frame at ``t_ns`` from the keyframe that shares the most track ids
        (``relocalise.most_shared``), when at least ``min_features`` pass the gates."""
        frame = self.keyframe_features(t_ns)
        found = None if frame is None else most_shared(keyframes, frame, min_features)
        if found is None:
            return None
        assert frame is not None
        tr = pair_frames(found[0].features, frame, self.rig, self.track_options)
        return (found[0], tr) if int(tr.inlier.sum()) >= min_features else None


class ImageFrames:
    """Tracks computed by the stereo front end (``svains.frontend.pipeline``) when the estimator
    reaches each stereo pair. Per-frame wall times (ms) are kept for profiles: ``frontend_ms``
    (``StereoFrontend.process``) and ``stage_ms`` (its stages); ``status_counts`` counts the
    front end's per-frame status (``ok``, ``contradicts_prior``, ...)."""

    kind = "images"

    def __init__(
        self, cam0: CameraCalib | None, cam1: CameraCalib | None, bundle: bool = False
    ) -> None:
        from svains.frontend.options import FrontendOptions
        from svains.frontend.pipeline import StereoFrontend

        if cam0 is None or cam1 is None:
            raise ConfigError("image-based vision needs the cam0 and cam1 calibrations")
        opts = FrontendOptions(bundle=bundle)
        self.frontend = StereoFrontend.from_calibration(cam0, cam1, opts)
        self.rig = self.frontend.rig
        self.pixel_noise_std = 1.0
        self._images: dict[int, tuple[U8, U8]] = {}
        self.frontend_ms: list[float] = []
        self.stage_ms: list[dict[str, float]] = []
        self.status_counts: dict[str, int] = {}
        self.track_log = TrackLog()

    def push(self, t_ns: int, left: U8, right: U8) -> bool:
        """Keep the pair until its turn (the Navigator hands over its own copies)."""
        self._images[int(t_ns)] = (np.asarray(left, np.uint8), np.asarray(right, np.uint8))
        return True

    def discard(self, t_ns: int) -> None:
        self._images.pop(int(t_ns), None)

    def reference_time_ns(self) -> int | None:
        """Time of the front end's reference frame (the k-1 of the next tracks; None before the
        first good frame). A motion prior for ``tracks_at`` must span [reference, t_k]: after a
        held or dropped frame the reference is older than the previous frame."""
        return self.frontend.reference_t_ns

    def tracks_at(self, t_ns: int, motion_prior: Egomotion | None = None) -> StereoTracks | None:
        """Front-end tracks from the previous processed frame to ``t_ns``. ``motion_prior``
        (``T_Ck_Ckm1`` predicted from the IMU, with covariance) seeds KLT and RANSAC and rejects
        estimates that contradict it (see ``StereoFrontend.process``)."""
        pair = self._images.pop(int(t_ns), None)
        if pair is None:
            return None
        t0 = time.perf_counter()
        tracks = self.frontend.process(int(t_ns), pair[0], pair[1], motion_prior)
        self.frontend_ms.append((time.perf_counter() - t0) * 1e3)
        self.stage_ms.append(dict(self.frontend.stats.timings_ms))
        status = self.frontend.stats.status or "none"
        self.status_counts[status] = self.status_counts.get(status, 0) + 1
        return _logged(self.track_log, tracks)

    def keyframe_features(self, t_ns: int) -> OrbStereo | None:
        """ORB features, stereo matches and points of the frame processed at ``t_ns`` (a
        keyframe's; None unless it was the last good frame)."""
        return self.frontend.keyframe_features(int(t_ns))

    def relocalisation_tracks(
        self, t_ns: int, keyframes: Sequence[Keyframe], min_features: int
    ) -> tuple[Keyframe, StereoTracks] | None:
        """Tracks to the frame at ``t_ns`` from the first ``RELOCALISE_TRIES`` of
        ``keyframes`` (given closest view first) by descriptors
        (``StereoFrontend.relocalise``): the one with the most RANSAC inliers, at least
        ``min_features``."""
        tried = list(keyframes[:RELOCALISE_TRIES])
        tr = self.frontend.relocalise(int(t_ns), [(k.t_ns, k.features) for k in tried],
                                      min_features)  # fmt: skip
        if tr is None:
            return None
        return next(k for k in tried if k.t_ns == tr.t_prev_ns), tr
