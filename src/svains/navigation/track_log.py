"""The left pixels of every frame's tracks, kept for ``tracks.csv``: in memory up to
``SPOOL_ROWS`` rows, the rest spilled to an unnamed temporary file as the run goes.

Kept whole in memory they grew 375 MB per hour of 5 Hz ``3d`` (about 1200 rows of 17 bytes per
frame, a user's probe), also in a live ``svains.Navigator`` that never writes them.
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
from collections.abc import Callable, Iterator
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Frame = tuple[int, I64, NDArray[np.float32], NDArray[np.bool_]]

# rows kept in memory before they are spilled (about 3.4 MB)
SPOOL_ROWS = 200_000


class TrackLog:
    """The left pixels of each frame's tracks, as the vision updater received them: per frame,
    ``track_id`` (M,), ``uv_left_px`` (M, 2) in the rectified rig (``raw`` False) or the raw
    left image (``raw`` True, see ``make_raw``), ``inlier`` (M,) the front end's flag (RANSAC and
    stereo gates). Float32 pixels; ``frames`` yields them in order, ``len`` counts them. Not
    for concurrent use (one thread adds, then reads: ``Navigator.close`` hands it out)."""

    def __init__(self, raw: bool = False) -> None:
        self.raw = raw
        self._mem: list[Frame] = []
        self._mem_rows = 0
        self._spool: IO[bytes] | None = None
        self._offsets: list[int] = []  # where each chunk of the spool starts
        self._n = 0
        self._map: Callable[[F64], F64] | None = None  # rectified -> raw, applied when read
        self._spool_failed = False

    def add(self, t_ns: int, track_id: I64, uv_left_px: F64, inlier: NDArray[np.bool_]) -> None:
        """Keep one frame's tracks (copies)."""
        frame = (int(t_ns), np.array(track_id, np.int64),
                 np.array(uv_left_px, np.float32).reshape(-1, 2), np.array(inlier, bool))
        self._mem.append(frame)
        self._mem_rows += frame[1].size
        self._n += 1
        if self._mem_rows >= SPOOL_ROWS and not self._spool_failed:
            self._spill()

    def __len__(self) -> int:
        return self._n

    @property
    def frames(self) -> Iterator[Frame]:
        """Every frame ``(t_ns, track_id, uv_left_px, inlier)`` in the order added (pixels raw
        after ``make_raw``)."""
        for t, ids, uv, inl in self._stored():
            if self._map is not None:
                uv = np.asarray(self._map(uv.astype(float)), np.float32).reshape(-1, 2)
            yield t, ids, uv, inl

    def make_raw(self, unrectify: Callable[[F64], F64]) -> None:
        """Pixels mapped by ``unrectify`` (rectified (N, 2) -> raw (N, 2)) from now on, frame by
        frame as they are read (a copy of the whole log doubled it at the end of a run)."""
        if not self.raw:
            self._map, self.raw = unrectify, True

    def _spill(self) -> None:
        m = self._mem
        start = None
        try:
            if self._spool is None:
                # lives as long as the log (closed and gone with it, also on a crash)
                self._spool = tempfile.TemporaryFile(prefix="svains-tracks-", buffering=0)  # noqa: SIM115
            start = self._spool.seek(0, 2)
            heads = np.array([[f[0], f[1].size] for f in m], np.int64).reshape(-1, 2)
            for a in (heads, *(np.concatenate([f[k] for f in m]) for k in (1, 2, 3))):
                np.save(self._spool, a)
        except OSError as exc:  # (no usable temporary folder raises FileNotFoundError)
            # a full or unwritable temporary folder must not end a run (a review: a live
            # Navigator died of ENOSPC mid-run): the tracks stay in memory from now on
            log.warning("the tracks kept for tracks.csv could not be spilled to a temporary "
                        "file (%s): they stay in memory", exc)  # fmt: skip
            self._spool_failed = True
            if self._spool is not None and start is not None:
                with contextlib.suppress(OSError):
                    self._spool.truncate(start)  # the partial chunk gives its space back
            return
        self._offsets.append(start)
        self._mem, self._mem_rows = [], 0

    def _stored(self) -> Iterator[Frame]:
        for off in list(self._offsets):
            assert self._spool is not None
            self._spool.seek(off)  # spills write at the end
            heads, ids, uv, inl = (np.load(self._spool) for _ in range(4))
            ends = np.cumsum(heads[:, 1])
            for (t, _n), b, e in zip(heads, ends - heads[:, 1], ends, strict=True):
                yield int(t), ids[b:e], uv[b:e], inl[b:e]
        yield from list(self._mem)

    def __getstate__(self) -> dict[str, Any]:
        # a temporary file does not travel, nor the map (a rectifier's whole remap tables:
        # 20 MB per pickled run, a review): the frames do, as read
        frames = list(self.frames)
        state = self.__dict__.copy()
        state.update(_mem=frames, _mem_rows=sum(f[1].size for f in frames), _spool=None,
                     _offsets=[], _map=None, _spool_failed=False)  # fmt: skip
        return state
