"""The GPS frame and the gyro's unit, checked against each other while the run goes.

Files are checked on load (``svains.datasets.validate.check_gps_against_gyro``); fixes and
samples fed to a :class:`svains.Navigator` never pass that way, so the estimator repeats the
test on them as they arrive: between two GPS fixes at least ``GPS_TURN_STEP_S`` apart, both
moving faster than ``GPS_TURN_MIN_SPEED_M_S``, the change of the GPS course (the horizontal
direction of its velocity, about ``gravity_W``'s up) is paired with the gyro's turn about the
vertical over the same interval (its rates projected on the mean specific force there, so no
mounting calibration is needed). Steps turning at least ``GPS_TURN_MIN_DEG`` by the gyro count,
and the counts, sums and verdict are those of the load-time test
(``svains.sensors.units.course_turn_problem``): a course turning against the gyro (a GPS in NED
against a z-up ``gravity_W``) or by another amount (a gyro in deg/s) is warned once each, not
refused: an online estimator does not stop mid-flight on its own inference. O(1) per fix beyond
the IMU samples of its interval.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import NDArray

from svains.navigation.imu_history import ImuHistory
from svains.sensors.units import (
    GPS_TURN_MIN_DEG,
    GPS_TURN_MIN_SPEED_M_S,
    GPS_TURN_STEP_S,
    course_turn_problem,
)

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


class CourseCheck:
    """Pairs, fix by fix, the GPS course's turn with the gyro's; warns on a mirrored GPS frame
    or a gyro in another unit."""

    def __init__(self, history: ImuHistory, g_W: F64) -> None:
        """``history``: the body-frame IMU samples the estimator keeps; ``g_W`` (3,) m/s²."""
        self.history = history
        self.g_W = np.asarray(g_W, dtype=float)
        up = -self.g_W / np.linalg.norm(self.g_W)
        e1 = np.cross(up, (1.0, 0.0, 0.0) if abs(up[0]) < 0.9 else (0.0, 1.0, 0.0))
        e1 /= np.linalg.norm(e1)
        self._e = (e1, np.cross(up, e1))  # (e1, e2, up) right-handed
        self._anchor: tuple[int, float, float] | None = None  # t_ns, course rad, speed m/s
        # sums over the counted steps: course·turn, course², turn², |turn|
        self._ab = self._aa = self._bb = self._abs_b = 0.0
        self.steps = 0
        self.warned: dict[str, str] = {}

    def observe_fix(self, t_ns: int, v_W_G: F64 | None) -> None:
        """A GPS fix at ``t_ns`` with velocity ``v_W_G`` (3,) m/s (None: nothing to compare)."""
        if v_W_G is None:
            return
        v = np.asarray(v_W_G, dtype=float)
        e1, e2 = self._e
        course = math.atan2(float(v @ e2), float(v @ e1))
        speed = math.hypot(float(v @ e1), float(v @ e2))
        if self._anchor is not None and t_ns - self._anchor[0] < GPS_TURN_STEP_S * 1e9:
            return
        anchor, self._anchor = self._anchor, (t_ns, course, speed)
        if anchor is None or min(anchor[2], speed) <= GPS_TURN_MIN_SPEED_M_S:
            return
        turn = self._gyro_turn_up(anchor[0], t_ns)
        if turn is None or abs(turn) <= math.radians(GPS_TURN_MIN_DEG):
            return
        d_course = math.remainder(course - anchor[1], 2.0 * math.pi)
        self._ab += d_course * turn
        self._aa += d_course * d_course
        self._bb += turn * turn
        self._abs_b += abs(turn)
        self.steps += 1
        got = self.figures()
        problem = None if got is None else course_turn_problem(*got, self.g_W)
        if problem is not None and problem[0] not in self.warned:
            kind, why = problem
            self.warned[kind] = why
            log.warning("online input: %s", why)

    def _gyro_turn_up(self, t0_ns: int, t1_ns: int) -> float | None:
        """The gyro's turn (rad) about the vertical over ``[t0_ns, t1_ns]``: its rates on the
        interval's mean specific force, trapezoids over the samples inside (None when the
        history no longer or not yet holds the interval)."""
        h = self.history
        t = h.t_ns
        if t.size < 2 or t[0] > t0_ns or t[-1] < t1_ns:
            return None
        i0 = int(np.searchsorted(t, t0_ns))
        i1 = int(np.searchsorted(t, t1_ns, side="right"))
        if i1 - i0 < 2:
            return None
        f = h.accel_B[i0:i1].mean(axis=0)
        norm = float(np.linalg.norm(f))
        if norm == 0.0:
            return None
        rate = h.gyro_B[i0:i1] @ (f / norm)
        dt = np.diff(t[i0:i1]) * 1e-9
        return float(np.sum(0.5 * (rate[1:] + rate[:-1]) * dt))

    def figures(self) -> tuple[float, int, float, float] | None:
        """(cosine, steps, gyro turn deg, course turn per gyro turn) over the counted steps, as
        ``gps_course_vs_imu_turn`` gives them on load; None before any."""
        if self.steps == 0 or self._aa == 0.0:
            return None
        cosine = self._ab / math.sqrt(self._aa * self._bb)
        return cosine, self.steps, math.degrees(self._abs_b), self._ab / self._bb

    def summary(self) -> dict[str, object]:
        """``steps`` compared, their ``cosine`` and ``turn_ratio`` (course over gyro; None before
        any), and the warnings given (``gps`` mirrored frame, ``gyro`` unit)."""
        got = self.figures()
        return {"steps": self.steps, "cosine": None if got is None else got[0],
                "turn_ratio": None if got is None else got[3],
                "warned": sorted(self.warned)}  # fmt: skip
