"""Plausibility of magnetometer, GPS and sonar samples before they reach the filter.

A dead magnetometer reads zeros, a hung one repeats its last vector; a sonar without echo may
report zero or a negative range; a frozen GPS receiver repeats its last fix. Fused, such
samples pull the attitude, the height or the position (issue 23: a dead magnetometer cost
``ins`` 2.7x its clean error, negative sonar ranges 5.2x, a frozen GPS stopped ``3d``, with no
warning). Each check returns why a sample is implausible, or None; the Navigator drops it and
counts it (``report.json`` ``dropped``), warning on the first few.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

# A magnetometer's field magnitude outside [1/5, 5] times the reference field's is not the
# Earth's field (local disturbances stay within ~2x; a dead sensor reads 0).
MAG_NORM_FACTOR = 5.0
# Identical vectors in a row from a sensor with noise: the sensor (or its driver) is stuck.
MAG_FROZEN_REPEATS = 5
# A GPS fix whose position equals the previous one to the last digit: a receiver (or driver)
# repeating its last solution, from the second identical fix in a row on (a real fix's noise
# never repeats to the last digit; KITTI raw's 37 fixes hold no repeat).
GPS_FROZEN_REPEATS = 2


class SampleChecks:
    """Per-stream plausibility state (the magnetometer's last vector and its repeats)."""

    def __init__(self, mag_reference_norm: float | None) -> None:
        """``mag_reference_norm``: the magnitude of the expected field (Gauss; None: unknown,
        the magnitude is then not checked)."""
        self._mag_ref = mag_reference_norm
        self._mag_last: F64 | None = None
        self._mag_repeats = 0
        self._gps_last: F64 | None = None
        self._gps_repeats = 0

    def magnetometer(self, m_S: F64) -> str | None:
        """Why the field ``m_S`` (3,) Gauss is implausible, or None."""
        m = np.asarray(m_S, dtype=float)
        if not np.all(np.isfinite(m)):
            return "non-finite magnetometer field"
        same = self._mag_last is not None and np.array_equal(m, self._mag_last)
        self._mag_repeats = self._mag_repeats + 1 if same else 0
        self._mag_last = m.copy()
        norm = float(np.linalg.norm(m))
        ref = self._mag_ref
        lo, hi = (0.0, np.inf) if not ref else (ref / MAG_NORM_FACTOR, ref * MAG_NORM_FACTOR)
        if norm == 0.0 or not lo <= norm <= hi:
            known = "unknown" if not ref else f"{ref:.3g} G"
            return (f"magnetometer field |m| = {norm:.3g} G, the reference field is {known} "
                    "(a dead or saturated sensor)")  # fmt: skip
        if self._mag_repeats >= MAG_FROZEN_REPEATS - 1:
            return f"magnetometer repeats the same vector {self._mag_repeats + 1} times (stuck)"
        return None

    def gps(self, p_W_G: F64, v_W_G: F64 | None = None) -> str | None:
        """Why the fix at ``p_W_G`` (3,) m with velocity ``v_W_G`` (3,) m/s (None: position
        only) is implausible (a non-finite value; the same position as the fixes before it,
        ``GPS_FROZEN_REPEATS`` times), or None."""
        p = np.asarray(p_W_G, dtype=float)
        if not np.all(np.isfinite(p)):
            return "non-finite GPS position"
        if v_W_G is not None and not np.all(np.isfinite(v_W_G)):
            return "non-finite GPS velocity"
        same = self._gps_last is not None and np.array_equal(p, self._gps_last)
        self._gps_repeats = self._gps_repeats + 1 if same else 0
        self._gps_last = p.copy()
        if self._gps_repeats >= GPS_FROZEN_REPEATS - 1:
            return f"GPS repeats the same position {self._gps_repeats + 1} times (frozen fix)"
        return None

    @staticmethod
    def sonar(range_m: float) -> str | None:
        """Why the range ``range_m`` (m) is implausible, or None."""
        r = float(np.asarray(range_m, dtype=float).reshape(-1)[0])
        if not np.isfinite(r):
            return "non-finite sonar range"
        if r <= 0.0:
            return f"sonar range {r:.3g} m is not positive (no echo)"
        return None


# Fed tracks: after this many features over at least ``TRACK_SIDE_MIN_FRAMES`` frames, a share
# of negative disparities (the right pixel right of the left one) this large says the left and
# right pixels are crossed (an image pair's test counts 0-2 of 700-1900 so on right pairs:
# ``frontend.stereo_check``). Features within 1 px of zero disparity (points at infinity) say
# nothing and are left out.
TRACK_SIDE_MIN_FEATURES = 60
TRACK_SIDE_MIN_FRAMES = 3
TRACK_SIDE_CROSSED_FRACTION = 0.8


class TrackSides:
    """Whether fed tracks' left and right pixels are crossed, judged once over their first
    frames; once judged crossed, every later frame's are exchanged (as crossed image streams
    are, ``frontend.stereo_check``)."""

    def __init__(self) -> None:
        self.negative = 0
        self.counted = 0
        self.frames = 0
        self.crossed: bool | None = None  # None: not judged yet

    def observe(self, uv_left: F64, uv_right: F64) -> str | None:
        """One frame's pixels (M, 2) each; the warning to give when this frame decides they are
        crossed (None otherwise)."""
        if self.crossed is not None:
            return None
        d = uv_left[:, 0] - uv_right[:, 0]
        d = d[np.abs(d) >= 1.0]
        self.negative += int(np.sum(d < 0.0))
        self.counted += int(d.size)
        self.frames += 1
        if self.frames < TRACK_SIDE_MIN_FRAMES or self.counted < TRACK_SIDE_MIN_FEATURES:
            return None
        self.crossed = self.negative >= TRACK_SIDE_CROSSED_FRACTION * self.counted
        if not self.crossed:
            return None
        return (f"{self.negative} of {self.counted} fed features lie at negative disparity (the "
                "right pixel right of the left one): uv_left and uv_right look crossed; they "
                "are exchanged from here on")
