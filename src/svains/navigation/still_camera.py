"""The camera's witness of a rest: the features' pixel motion over the last half second.

The IMU's rest test (``navigation.zupt.StaticTest``) cannot tell a rest from a steady motion:
a robot driving straight at 0.8 m/s passed it on most of its 0.5 s windows, and with
``zupt.after_start`` the filter met hundreds of "v = 0" updates while driving (a user's probe:
`ins` 456 refused and 90 fused, velocity NEES 1640). A camera that moves sees its features
move: ``StillCamera`` keeps the left pixels of each frame's tracks over the last
``window_s`` and calls the camera still when the median displacement of the features seen
at both ends of that span stays under ``still_px``. A forward motion moves the features near
the image centre little, and noise moves every feature: the span (not one frame pair) and the
median over many features keep the two apart (0.8 m/s over 0.5 s: about 10 px at 5-10 m; 0.5 px
pixel noise: a median of 0.8 px).
"""

from __future__ import annotations

import collections

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import StereoTracks

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class StillCamera:
    """Whether the camera stood still over the last ``window_s`` (see the module docstring):
    ``observe`` each frame's tracks, ask ``still`` at a time."""

    def __init__(self, window_s: float, still_px: float, min_features: int = 10) -> None:
        self.window_ns = int(window_s * 1e9)
        self.still_px = float(still_px)
        self.min_features = int(min_features)
        # (t_ns, sorted track ids, their left pixels (M, 2)) of the recent frames
        self._frames: collections.deque[tuple[int, I64, F64]] = collections.deque()

    def observe(self, tr: StereoTracks | None) -> None:
        """The tracks ending at a frame (None: a frame without tracks, which ends the span)."""
        if tr is None or tr.track_id.size == 0:
            self._frames.clear()
            return
        order = np.argsort(tr.track_id, kind="stable")
        ids = np.asarray(tr.track_id)[order]
        self._frames.append((int(tr.t_ns), ids, np.asarray(tr.uv_left, float)[order]))
        # keep the newest frame at least ``window_ns`` before the latest, not older ones
        while len(self._frames) > 2 and self._frames[-1][0] - self._frames[1][0] >= self.window_ns:
            self._frames.popleft()

    def still(self, t_ns: int) -> bool | None:
        """True when the camera stood still over the ``window_s`` before its latest frame,
        False when it moved, None when it cannot tell (no frame within ``window_s`` before
        ``t_ns``, a span shorter than ``window_s``, or fewer than ``min_features`` features
        seen at both of its ends)."""
        if len(self._frames) < 2:
            return None
        t_last, ids_last, uv_last = self._frames[-1]
        if t_ns - t_last > self.window_ns:
            return None
        first = None
        for frame in reversed(self._frames):
            if t_last - frame[0] >= self.window_ns:
                first = frame
                break
        if first is None:
            return None
        _, ids_first, uv_first = first
        common, i_last, i_first = np.intersect1d(ids_last, ids_first, return_indices=True)
        if common.size < self.min_features:
            return None
        moved = np.linalg.norm(uv_last[i_last] - uv_first[i_first], axis=1)
        return bool(np.median(moved) < self.still_px)
