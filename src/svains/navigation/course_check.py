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

:class:`MagTurnCheck` does the same for the magnetometer (``sensors.units.mag_turn_vs_gyro`` on
load): the field in the body frame must turn against the gyro's turn about the vertical; one
that turns with it over 4 steps and 45° comes from axes mirrored against the IMU's through the
calibration, and is warned once; the caller stops fusing it.
"""

from __future__ import annotations

import logging
import math
from collections import deque

import numpy as np
from numpy.typing import NDArray

from svains.navigation.heading_check import horizontal_basis
from svains.navigation.imu_history import ImuHistory
from svains.sensors.units import (
    GPS_TURN_MIN_DEG,
    GPS_TURN_MIN_SPEED_M_S,
    GPS_TURN_STEP_S,
    MAG_MEAN_S,
    MAG_TURN_STEP_S,
    course_turn_problem,
    mag_turn_problem,
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
        e1, e2 = horizontal_basis(-self.g_W / np.linalg.norm(self.g_W))
        self._e = (e1, e2)  # (e1, e2, up) right-handed
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
        got = vertical_turn(self.history, t0_ns, t1_ns)
        return None if got is None else got[0]

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


def vertical_turn(history: ImuHistory, t0_ns: int, t1_ns: int) -> tuple[float, F64] | None:
    """The gyro's turn (rad) about the vertical over ``[t0_ns, t1_ns]`` and that vertical (3,),
    unit, body frame): its rates on the interval's mean specific force, trapezoids over the
    samples inside (None when the history no longer or not yet holds the interval)."""
    t = history.t_ns
    if t.size < 2 or t[0] > t0_ns or t[-1] < t1_ns:
        return None
    i0 = int(np.searchsorted(t, t0_ns))
    i1 = int(np.searchsorted(t, t1_ns, side="right"))
    if i1 - i0 < 2:
        return None
    f = history.accel_B[i0:i1].mean(axis=0)
    norm = float(np.linalg.norm(f))
    if norm == 0.0:
        return None
    up = f / norm
    rate = history.gyro_B[i0:i1] @ up
    dt = np.diff(t[i0:i1]) * 1e-9
    return float(np.sum(0.5 * (rate[1:] + rate[:-1]) * dt)), up


class MagTurnCheck:
    """Pairs, step by step, the magnetic field's turn in the body frame with the gyro's; warns
    once when it turns with the body (module docstring)."""

    def __init__(self, history: ImuHistory, R_B_S: F64) -> None:
        """``history``: the body-frame IMU samples; ``R_B_S`` (3, 3): the magnetometer's mount."""
        self.history = history
        self.R_B_S = np.asarray(R_B_S, dtype=float)
        self._recent: deque[tuple[int, F64]] = deque()  # the last MAG_MEAN_S of samples, body
        self._anchor: tuple[int, F64] | None = None  # t_ns, mean field (body frame)
        self._ab = self._aa = self._bb = self._abs_b = 0.0
        self.steps = 0
        self.warned: str | None = None

    def observe(self, t_ns: int, m_S: F64) -> bool:
        """A magnetometer sample ``m_S`` (3,) at ``t_ns``; True once the field has been found
        turning with the body (from this sample on)."""
        if self.warned is not None:
            return True
        self._recent.append((t_ns, self.R_B_S @ np.asarray(m_S, float)))
        cut = t_ns - int(MAG_MEAN_S * 1e9)
        while self._recent[0][0] < cut:
            self._recent.popleft()
        if self._anchor is not None and t_ns - self._anchor[0] < MAG_TURN_STEP_S * 1e9:
            return False
        m_end = np.mean([m for _, m in self._recent], axis=0)
        anchor, self._anchor = self._anchor, (t_ns, m_end)
        if anchor is None:
            return False
        got = vertical_turn(self.history, anchor[0], t_ns)
        if got is None or abs(got[0]) <= math.radians(GPS_TURN_MIN_DEG):
            return False
        turn, up = got
        d_field = _angle_about(up, anchor[1], m_end)
        self._ab += d_field * -turn
        self._aa += d_field * d_field
        self._bb += turn * turn
        self._abs_b += abs(turn)
        self.steps += 1
        if self._aa == 0.0:
            return False
        cosine = self._ab / math.sqrt(self._aa * self._bb)
        problem = mag_turn_problem(cosine, self.steps, math.degrees(self._abs_b))
        if problem is None:
            return False
        self.warned = problem
        log.warning("online input: %s; it is not fused from now on", problem)
        return True

    def summary(self) -> dict[str, object]:
        """``steps`` compared, their ``cosine`` (+1: the field turns against the body, as it
        must; None before any) and whether it was found turning with it (``warned``)."""
        cosine = (self._ab / math.sqrt(self._aa * self._bb)
                  if self.steps and self._aa > 0 else None)  # fmt: skip
        return {"steps": self.steps, "cosine": cosine, "warned": self.warned is not None}


def _angle_about(up: F64, a: F64, b: F64) -> float:
    """The signed angle (rad) from ``a`` to ``b`` (3,) about the unit axis ``up``, both
    projected on the plane normal to it."""
    a_h = a - (a @ up) * up
    b_h = b - (b @ up) * up
    return math.atan2(float(np.cross(a_h, b_h) @ up), float(a_h @ b_h))
