"""Where the vision updaters get their stereo tracks: ``features0`` or images via the front end.

Both sources give ``frame_times()`` (int64 ns, the frames that carry tracks from a previous frame)
and ``tracks_at(t_ns, motion_prior=None) -> StereoTracks | None``.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset, FeatureStream
from svains.errors import ConfigError, DatasetError
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.navigation.tracks import TrackOptions, tracks_from_features

I64 = NDArray[np.int64]
U8 = NDArray[np.uint8]

log = logging.getLogger(__name__)

SourceName = Literal["auto", "features", "images"]


def rig_from_dataset(ds: Dataset) -> RectifiedStereo:
    """The rectified pair that ``cam0``/``cam1`` define (``features0`` pixels live in it)."""
    if ds.cam0 is None or ds.cam1 is None:
        raise DatasetError(f"{ds.root}: vision methods need cam0 and cam1 calibrations")
    from svains.frontend.rectify import StereoRectifier

    return StereoRectifier.from_calibration(ds.cam0, ds.cam1).rig


def decimate_features(fs: FeatureStream, stride: int) -> FeatureStream:
    """Keep every ``stride``-th frame of a feature stream (e.g. 20 Hz -> 5 Hz with 4)."""
    if stride < 1:
        raise ConfigError(f"frame_stride must be >= 1, got {stride}")
    if stride == 1:
        return fs
    times = fs.frame_times()[::stride]
    keep = np.isin(fs.t_ns, times)
    return FeatureStream(
        t_ns=fs.t_ns[keep], track_id=fs.track_id[keep], uv_left=fs.uv_left[keep],
        uv_right=fs.uv_right[keep], pixel_noise_std=fs.pixel_noise_std,
    )


class FeatureTrackSource:
    """Tracks precomputed from the recorded ``features0`` stream."""

    kind = "features"

    def __init__(
        self, ds: Dataset, rig: RectifiedStereo, track_options: TrackOptions, frame_stride: int = 1
    ) -> None:
        if ds.features is None:
            raise DatasetError(f"{ds.root}: no features0 stream (use images instead)")
        self.rig = rig
        self.pixel_noise_std = float(ds.features.pixel_noise_std)
        fs = decimate_features(ds.features, frame_stride)
        tracks = tracks_from_features(fs, rig, track_options)
        self._by_time = {tr.t_ns: tr for tr in tracks}
        self._times = np.array(sorted(self._by_time), dtype=np.int64)

    def frame_times(self) -> I64:
        return self._times

    def tracks_at(self, t_ns: int, motion_prior: Egomotion | None = None) -> StereoTracks | None:
        """Recorded tracks ending at ``t_ns`` (``motion_prior`` is not needed here)."""
        return self._by_time.get(int(t_ns))


class ImageTrackSource:
    """Tracks computed on the fly by the stereo front end (``svains.frontend.pipeline``).

    Frames are asked for in time order, so the next stereo pair is decoded by a background thread
    (``prefetch=True``) while the front end and the filter work on the current one: PNG decoding
    in OpenCV releases the GIL, and on a 752x480 pair it costs about half the front end.
    Per-frame wall times (ms) are kept for profiles: ``load_ms`` (waiting for the images),
    ``frontend_ms`` (``StereoFrontend.process``) and ``stage_ms`` (its stages);
    ``status_counts`` counts the front end's per-frame status (``ok``, ``contradicts_prior``, ...).
    """

    kind = "images"

    def __init__(self, ds: Dataset, frame_stride: int = 1, prefetch: bool = True) -> None:
        from svains.datasets.loader import stereo_pairs
        from svains.frontend.pipeline import StereoFrontend

        if ds.cam0 is None or ds.cam1 is None or ds.left is None or ds.right is None:
            raise DatasetError(f"{ds.root}: image-based vision needs cam0/cam1 images")
        self._ds = ds
        self.frontend = StereoFrontend.from_calibration(ds.cam0, ds.cam1)
        self.rig = self.frontend.rig
        self.pixel_noise_std = 1.0
        t, il, ir = stereo_pairs(ds)
        if t.size < 2:
            raise DatasetError(
                f"{ds.root}: {t.size} stereo pair(s) with images on disk; image-based vision "
                "needs at least 2"
            )
        sel = slice(None, None, max(1, frame_stride))
        self._times = np.asarray(t[sel], np.int64)
        self._index = {int(tt): (int(a), int(b)) for tt, a, b in zip(t[sel], il[sel], ir[sel],
                                                                     strict=True)}
        self._prefetch = prefetch
        self._pool: ThreadPoolExecutor | None = None
        self._pending: dict[int, Future[tuple[U8, U8]]] = {}
        self.load_ms: list[float] = []
        self.frontend_ms: list[float] = []
        self.stage_ms: list[dict[str, float]] = []
        self.status_counts: dict[str, int] = {}

    def frame_times(self) -> I64:
        return self._times

    def reference_time_ns(self) -> int | None:
        """Time of the front end's reference frame (the k-1 of the next tracks; None before the
        first good frame). A motion prior for ``tracks_at`` must span [reference, t_k]: after a
        held or dropped frame the reference is older than the previous frame."""
        return self.frontend.reference_t_ns

    def _load(self, ij: tuple[int, int]) -> tuple[U8, U8]:
        assert self._ds.left is not None and self._ds.right is not None
        return self._ds.left.load(ij[0]), self._ds.right.load(ij[1])

    def _images(self, t_ns: int, ij: tuple[int, int]) -> tuple[U8, U8]:
        """The pair at ``t_ns`` (prefetched if it was), and start decoding the next one."""
        fut = self._pending.pop(t_ns, None)
        # A jump (frames asked out of order) leaves stale prefetches: drop them.
        for stale in self._pending.values():
            stale.cancel()
        self._pending.clear()
        if self._prefetch:
            k = int(np.searchsorted(self._times, t_ns, side="right"))
            if k < self._times.size:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="svains-png")
                t_next = int(self._times[k])
                self._pending[t_next] = self._pool.submit(self._load, self._index[t_next])
        # An unreadable file raises its DatasetError here, as without prefetching.
        return fut.result() if fut is not None else self._load(ij)

    def tracks_at(self, t_ns: int, motion_prior: Egomotion | None = None) -> StereoTracks | None:
        """Front-end tracks from the previous processed frame to ``t_ns``. ``motion_prior``
        (``T_Ck_Ckm1`` predicted from the IMU, with covariance) seeds KLT and RANSAC and rejects
        estimates that contradict it (see ``StereoFrontend.process``)."""
        ij = self._index.get(int(t_ns))
        if ij is None:
            return None
        t0 = time.perf_counter()
        left, right = self._images(int(t_ns), ij)
        t1 = time.perf_counter()
        tracks = self.frontend.process(int(t_ns), left, right, motion_prior)
        self.load_ms.append((t1 - t0) * 1e3)
        self.frontend_ms.append((time.perf_counter() - t1) * 1e3)
        self.stage_ms.append(dict(self.frontend.stats.timings_ms))
        status = self.frontend.stats.status or "none"
        self.status_counts[status] = self.status_counts.get(status, 0) + 1
        return tracks

    def close(self) -> None:
        """Stop the prefetch thread (also done at garbage collection)."""
        for fut in self._pending.values():
            fut.cancel()
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None


def make_source(
    ds: Dataset, source: SourceName, track_options: TrackOptions, frame_stride: int = 1
) -> FeatureTrackSource | ImageTrackSource:
    """``features`` (recorded tracks), ``images`` (front end) or ``auto`` (features if present)."""
    if source not in ("auto", "features", "images"):
        raise ConfigError(f"vision source must be auto, features or images, got {source!r}")
    if source == "features" or (source == "auto" and ds.has_stream("features")):
        return FeatureTrackSource(ds, rig_from_dataset(ds), track_options, frame_stride)
    return ImageTrackSource(ds, frame_stride)
