"""Stamps carried across a clock that steps back mid-run (a driver restart, an NTP step).

Fed online, a host clock that goes back 10 s made every IMU sample of the next 10 s look older
than the last one: they were dropped, the filter's time stood still while the vehicle moved,
vision was then refused as a jump and the run diverged (a user's probe: 514 m). A step back of
more than ``STEP_BACK_S`` that the next IMU sample confirms (a single stale sample is dropped)
is taken for a clock step instead: later IMU stamps are shifted to go on from the last
sample, one warning says so, and every other stream's
stamp takes whichever shift seen so far (none, or the steps' sums) puts it nearest the IMU's
time: a measurement stamped before the step and delivered late keeps its stamp, one stamped
after it on the same stepped clock is carried like the IMU. Smaller steps back stay what they
were: out-of-order samples, dropped and counted. A step forward is a gap (its own handling).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

log = logging.getLogger(__name__)

# An IMU stamp this far before the last sample is a clock stepping back, not a late sample.
STEP_BACK_S = 1.0


class ClockSteps:
    """The shifts (ns) applied to stamps after IMU clock steps back; ``steps`` lists them."""

    def __init__(self, step_back_s: float = STEP_BACK_S) -> None:
        self._step_ns = round(step_back_s * 1e9)
        self.shift_ns = 0  # applied to IMU stamps now
        self._shifts = [0]  # every shift in force at some time, oldest first
        self._imu_now_ns: int | None = None
        self._candidate_ns: int | None = None  # a first sample far back, raw stamp
        self.steps: list[dict[str, float]] = []

    def imu(
        self, t_ns: int, last_ns: int | None, period_ns: Callable[[], int], origin_ns: int | None
    ) -> int:
        """The IMU stamp ``t_ns`` on the run's clock; ``last_ns``: the last accepted sample's
        (run clock), ``period_ns()`` the sample spacing to leave after it, ``origin_ns`` the
        run's first stamp (for the warning)."""
        t = t_ns + self.shift_ns
        if last_ns is None or t >= last_ns - self._step_ns:
            self._candidate_ns = None
        elif self._candidate_ns is None or not 0 < t_ns - self._candidate_ns <= 3 * period_ns():
            # The first sample far back: a stray (a stale message) until the next one follows
            # it on the same clock; the caller drops it as out of order.
            self._candidate_ns = t_ns
        else:
            # the held-out first sample goes one period after the last: the step's size
            back_ns = last_ns - (self._candidate_ns + self.shift_ns)
            self._candidate_ns = None
            step_ns = back_ns + period_ns()
            self.shift_ns += step_ns
            self._shifts.append(self.shift_ns)
            at_s = (last_ns - (origin_ns if origin_ns is not None else last_ns)) * 1e-9
            # the step: how far the new clock's first sample sits behind where it was due (one
            # period after the last; "1.195 s" was said of a 1.2 s step: a user's probe)
            self.steps.append({"at_s": round(at_s, 6), "back_s": round(step_ns * 1e-9, 9)})
            log.warning(
                "%.3f s into the run: the IMU clock stepped back %.3f s (a clock reset or a "
                "driver restart?): later stamps of every stream on that clock are shifted "
                "%+.3f s to go on from the last sample", at_s, step_ns * 1e-9,
                step_ns * 1e-9)  # fmt: skip
            t = t_ns + self.shift_ns
        self._imu_now_ns = t if self._imu_now_ns is None else max(self._imu_now_ns, t)
        return t

    def other(self, t_ns: int) -> int:
        """A camera/GPS/magnetometer/sonar stamp on the run's clock."""
        if len(self._shifts) == 1 or self._imu_now_ns is None:
            return t_ns
        now = self._imu_now_ns
        return min((t_ns + s for s in self._shifts), key=lambda t: abs(t - now))
