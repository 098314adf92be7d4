"""Stereo pairs read from a data set for a replay; an unreadable file drops its pair."""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.errors import DatasetError

log = logging.getLogger(__name__)
U8 = NDArray[np.uint8]
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
        self.dropped = 0

    def read(self, i_left: int, i_right: int, t_ns: int) -> tuple[U8, U8] | None:
        """Images ``i_left``/``i_right`` of the pair at ``t_ns`` (8-bit grey), or None."""
        try:
            return self._left.load(int(i_left)), self._right.load(int(i_right))
        except DatasetError as exc:
            self.dropped += 1
            if self.dropped <= _WARN_FIRST or self.dropped % _WARN_EVERY == 0:
                log.warning("t=%.3f s: stereo pair dropped (%d so far): %s", t_ns * 1e-9,
                            self.dropped, exc)  # fmt: skip
            return None
