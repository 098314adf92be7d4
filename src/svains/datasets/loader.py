"""Open any supported data set and walk its streams in time order."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.asl_reader import find_mav0, read_asl
from svains.datasets.kitti import is_kitti, read_kitti
from svains.datasets.stereo_sync import match_stereo
from svains.datasets.types import Dataset, ImageStream
from svains.datasets.validate import vet_streams
from svains.errors import ConfigError, DatasetError

log = logging.getLogger(__name__)
U8 = NDArray[np.uint8]

# Tie order at equal timestamps: IMU first (a filter propagates up to t before updating at t).
STREAM_ORDER: tuple[str, ...] = (
    "imu", "groundtruth", "gps", "mag", "sonar", "left", "right", "features",
)  # fmt: skip


def load_dataset(
    path: Path | str,
    calib: Path | str | None = None,
    imu_calib: Path | str | None = None,
    topics: dict[str, str | None] | None = None,
) -> Dataset:
    """Read a data set, its kind auto-detected: an ASL/EuRoC folder (root or ``mav0/``), a
    TUM-VI sequence, a KITTI odometry folder, or a ROS1/ROS2 bag (``topics``: role -> topic).

    ``calib`` (Kalibr camchain-imucam.yaml) and ``imu_calib`` (Kalibr imu.yaml) replace the
    data set's own calibration (``datasets/kalibr.py``).
    """
    from svains.datasets.kalibr import apply_kalibr, kalibr_topics
    from svains.datasets.rosbag import is_bag, read_bag
    from svains.datasets.tumvi import is_tumvi, read_tumvi

    p = Path(path)
    if not p.exists():
        raise DatasetError(f"data set folder not found: {p}")
    if topics and not is_bag(p):
        raise ConfigError(f"replay.topics (--topic) names a bag's topics; {p} is not a bag "
                          "(.bag, .db3, .mcap)")  # fmt: skip
    if is_bag(p):
        ds = read_bag(p, topics, hints=kalibr_topics(calib, imu_calib))
        if calib is None and ds.left is not None:
            log.warning("%s: a bag has no camera calibration; pass a Kalibr camchain (--calib)", p)
    elif not p.is_dir():
        raise DatasetError(f"not a folder or a bag (.bag, .db3, .mcap): {p}")
    elif is_tumvi(p):
        ds = read_tumvi(p)
    elif find_mav0(p) is not None:
        # a sensor.yaml the Kalibr files replace may be absent (a folder of tables and images)
        ds = read_asl(p, frozenset({*(["cameras"] if calib is not None else []),
                                    *(["imu"] if imu_calib is not None else [])}))
    elif is_kitti(p):
        ds = read_kitti(p)
    else:
        raise DatasetError(
            f"{p}: unrecognised data set (expected an ASL mav0/ folder, KITTI calib.txt + "
            "image_0/, or a ROS bag)"
        )
    if calib is not None or imu_calib is not None:
        ds = apply_kalibr(ds, calib, imu_calib)
    vet_streams(ds)
    return ds


def stream_times(ds: Dataset) -> dict[str, np.ndarray]:
    """Timestamps (int64 ns) of every present stream, keyed by its ``Dataset`` attribute name.

    ``features`` gives its distinct frame times.
    """
    out: dict[str, np.ndarray] = {}
    for name in STREAM_ORDER:
        s = getattr(ds, name)
        if s is None:
            continue
        out[name] = s.frame_times() if name == "features" else np.asarray(s.t_ns, np.int64)
    return out


def stereo_pairs(
    ds: Dataset, tol_ns: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames present in both cameras: (t_ns (P,), index into ``ds.left``, index into ``ds.right``).

    A left frame is paired with the nearest right frame within ``tol_ns`` (default: the data
    set's ``stereo_tol_ns``, see ``datasets.stereo_sync``); ``t_ns`` is the left time. Frames
    whose partner image is absent are dropped.
    """
    if ds.left is None or ds.right is None:
        raise DatasetError(f"{ds.root}: stereo pairs need both cam0 and cam1 images")
    tl = np.asarray(ds.left.t_ns, np.int64)
    idx_l, idx_r = match_stereo(tl, ds.right.t_ns, ds.stereo_tol_ns if tol_ns is None else tol_ns)
    return tl[idx_l], idx_l, idx_r


_WARN_FIRST = 3  # drops warned one by one; after them, one warning per _WARN_EVERY
_WARN_EVERY = 100


class PairReader:
    """Reads the cam0/cam1 images of ``ds``; a pair with a file that cannot be read is dropped
    with a warning: one corrupt or truncated file is a lost frame, as a camera driver's is, not
    the end of the run (the vision-gap report counts what the run lost; a run that fuses no
    vision at all still fails). ``dropped`` counts the pairs dropped."""

    def __init__(self, ds: Dataset) -> None:
        if ds.left is None or ds.right is None:
            raise DatasetError(f"{ds.root}: no cam0/cam1 images")
        self._left, self._right = ds.left, ds.right
        # (width, height) each camera's calibration holds; None: not checked
        self._sizes = tuple(None if c is None else tuple(int(v) for v in c.resolution)
                            for c in (ds.cam0, ds.cam1))  # fmt: skip
        self.dropped = 0

    def _load(self, stream: ImageStream, i: int, size: tuple[int, ...] | None) -> U8:
        img = stream.load(i)
        if size is not None and (img.shape[1], img.shape[0]) != size:
            # the load checks only the first image; a rectifier given another size would
            # raise deep in OpenCV or track on a wrong geometry
            raise DatasetError(f"image is {img.shape[1]}x{img.shape[0]} px, the calibration's "
                               f"resolution is {size[0]}x{size[1]}: {stream.paths[i]}")  # fmt: skip
        return img

    def read(self, i_left: int, i_right: int, t_ns: int) -> tuple[U8, U8] | None:
        """Images ``i_left``/``i_right`` of the pair at ``t_ns`` (8-bit grey), or None."""
        try:
            return (self._load(self._left, int(i_left), self._sizes[0]),
                    self._load(self._right, int(i_right), self._sizes[1]))  # fmt: skip
        except DatasetError as exc:
            self.dropped += 1
            if self.dropped <= _WARN_FIRST or self.dropped % _WARN_EVERY == 0:
                log.warning("t=%.3f s: stereo pair dropped (%d so far): %s", t_ns * 1e-9,
                            self.dropped, exc)  # fmt: skip
            return None


def iter_events(
    ds: Dataset,
    streams: Sequence[str] | None = None,
    t_start_ns: int | None = None,
    t_end_ns: int | None = None,
) -> Iterator[tuple[int, str, int]]:
    """Yield ``(t_ns, stream_name, index)`` of every sample of ``streams`` in time order.

    Names are ``Dataset`` attributes (see ``STREAM_ORDER``); ``index`` indexes that stream (for
    ``features``: the frame in ``features.frame_times()``). ``None`` means every present stream.
    The window is ``t_start_ns <= t <= t_end_ns``. Ties follow ``STREAM_ORDER`` (IMU first), then
    index. The merge order is computed once (int arrays); samples are yielded lazily.
    """
    times = stream_times(ds)
    names = list(times) if streams is None else list(streams)
    for n in names:
        if n not in STREAM_ORDER:
            raise ValueError(f"unknown stream '{n}' (expected one of {', '.join(STREAM_ORDER)})")
        if n not in times:
            raise DatasetError(f"{ds.root}: stream '{n}' is not in this data set")
    t_parts, prio_parts, idx_parts = [], [], []
    for n in names:
        t = times[n]
        sel = np.ones(t.size, bool)
        if t_start_ns is not None:
            sel &= t >= t_start_ns
        if t_end_ns is not None:
            sel &= t <= t_end_ns
        idx = np.flatnonzero(sel)
        t_parts.append(t[idx])
        idx_parts.append(idx)
        prio_parts.append(np.full(idx.size, STREAM_ORDER.index(n)))
    if not t_parts:
        return
    t_all = np.concatenate(t_parts)
    prio = np.concatenate(prio_parts)
    idx_all = np.concatenate(idx_parts)
    order = np.lexsort((idx_all, prio, t_all))
    for k in order.tolist():
        yield int(t_all[k]), STREAM_ORDER[prio[k]], int(idx_all[k])
