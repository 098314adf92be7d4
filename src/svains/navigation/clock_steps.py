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

A clock of one other stream alone stepping back (a camera driver restarted, the IMU's steady)
made every later frame "late": dropped one by one, the run went on as a pure INS and diverged (a
user's probe: 151 m). Such a stream's step is taken the same way, per stream: a stamp that lags
the IMU's time by more than ``STEP_BACK_S`` more than the stream's stamps did, and is either
before the stream's last or (a regular stream slower than the step) that much short of its
spacing, confirmed by the stream's next stamp lagging alike after the IMU's time went on (stale
messages re-sent in a burst do not; a delivery delay keeps the spacing), while the IMU's clock
is not stepping, shifts that stream's later stamps to go on as before the step (a regular
stream one spacing after its last stamp, others lagging the IMU's time as before), with a
warning naming the stream. A stream's step that the IMU's own step then explains is undone (one
step); the lags taken while an IMU gap held the IMU's time still are forgotten, those from
before the gap kept.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

# An IMU stamp this far before the last sample is a clock stepping back, not a late sample.
STEP_BACK_S = 1.0


@dataclass
class _Stream:
    """One non-IMU stream's own clock: its shift (ns), last stamp on the run's clock, its
    recent lags behind the IMU's time when fed and spacings (ns), a first stamp far back
    awaiting confirmation (raw ns) with its lag, and its last step (ns, the IMU's time then,
    its report entry) while the IMU's own step may still explain it."""

    shift_ns: int = 0
    last_ns: int | None = None
    # (lag, the IMU's time when it was taken), one per IMU time
    lags: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=9))
    spacings_ns: deque[int] = field(default_factory=lambda: deque(maxlen=9))
    # a first stamp far back: raw, its lag, the IMU's time then, the stamp on the run's clock
    candidate: tuple[int, int, int, int] | None = None
    last_step: tuple[int, int, dict[str, float | str]] | None = None


def _median(values: Sequence[int]) -> int | None:
    return sorted(values)[len(values) // 2] if values else None


def _spread(values: Sequence[int]) -> int:
    return max(values) - min(values) if values else 0


def _lag_values(s: _Stream) -> list[int]:
    return [lag for lag, _ in s.lags]



# A confirming stamp's lag behind the IMU's time agrees with the first's within the spread of
# the stream's lags before, at least this (ns): stamps fed as they come (a real step) lag alike
# (an IMU fed in 100 ms batches spreads them); a regular stream's spacings within a tenth of
# their median, at least this, make it regular.
LAG_AGREE_MIN_NS = 10_000_000
# A stream's step is judged against the median lag of at least this many stamps before it.
MIN_LAGS = 3
# A stream's step the IMU's own step explains (the same size, this soon before it) is undone.
RECONCILE_NS = 5_000_000_000


class ClockSteps:
    """The shifts (ns) applied to stamps after IMU clock steps back; ``steps`` lists them."""

    def __init__(self, step_back_s: float = STEP_BACK_S) -> None:
        self._step_ns = round(step_back_s * 1e9)
        self.shift_ns = 0  # applied to IMU stamps now
        self._shifts = [0]  # every shift in force at some time, oldest first
        self._imu_now_ns: int | None = None
        self._candidate_ns: int | None = None  # a first sample far back, raw stamp
        self.steps: list[dict[str, float | str]] = []
        self._streams: dict[str, _Stream] = {}
        self._origin_ns: int | None = None

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
            # the step: how far the new clock's first sample sits behind where it was due (one
            # period after the last; "1.195 s" was said of a 1.2 s step: a user's probe)
            at_s = self._record("imu", last_ns, step_ns)["at_s"]
            log.warning(
                "%.3f s into the run: the IMU clock stepped back %.3f s (a clock reset or a "
                "driver restart?): later stamps of every stream on that clock are shifted "
                "%+.3f s to go on from the last sample", at_s, step_ns * 1e-9,
                step_ns * 1e-9)  # fmt: skip
            t = t_ns + self.shift_ns
            if self._imu_now_ns is not None:
                self._reconcile(step_ns, self._imu_now_ns)
        stood = self._imu_now_ns
        if stood is not None and t - stood > self._step_ns:
            # An IMU gap: the other streams' lags taken while its time stood still say nothing
            # of their clocks (a frame out of order after the gap was taken for a step: a
            # user's probe); those from before it still do (a camera clock stepping back in
            # the gap, a USB reset, was missed when they went too: a review).
            for other in self._streams.values():
                other.lags = deque((p for p in other.lags if p[1] != stood), maxlen=9)
                if other.candidate is not None and other.candidate[2] == stood:
                    other.candidate = None
        self._imu_now_ns = t if self._imu_now_ns is None else max(self._imu_now_ns, t)
        if self._origin_ns is None:
            self._origin_ns = origin_ns if origin_ns is not None else t
        return t

    def other(self, t_ns: int, stream: str) -> int:
        """A camera/GPS/magnetometer/sonar stamp on the run's clock; ``stream`` names its clock
        (a step of that stream's alone is carried across the same way as the IMU's)."""
        s = self._streams.get(stream)
        if s is None:
            s = self._streams[stream] = _Stream()
        t = self._nearest(t_ns + s.shift_ns)
        now = self._imu_now_ns
        if now is not None and len(s.lags) >= MIN_LAGS and s.last_ns is not None:
            step = self._stream_step(s, t_ns, t, now)
            if step is None:
                return t  # held out: a stale message until the next stamp confirms a step
            if step:
                assert s.last_ns is not None
                s.shift_ns += step
                entry = self._record(stream, s.last_ns, step)
                s.last_step = (step, now, entry)
                log.warning(
                    "%.3f s into the run: the %s clock stepped back %.3f s while the IMU's went "
                    "on (a driver restart?): its later stamps are shifted %+.3f s to keep to the "
                    "IMU's", float(entry["at_s"]), stream, step * 1e-9, step * 1e-9)  # fmt: skip
                t = self._nearest(t_ns + s.shift_ns)
        else:
            s.candidate = None
        if now is not None:
            if s.lags and s.lags[-1][1] == now:
                # one lag per IMU time: the stamps of an IMU gap (its time standing still)
                # would push every lag from before it out
                s.lags.pop()
            s.lags.append((now - t, now))
        if s.last_ns is not None and t > s.last_ns:
            s.spacings_ns.append(t - s.last_ns)
        s.last_ns = t if s.last_ns is None else max(s.last_ns, t)
        return t

    def _stream_step(self, s: _Stream, t_ns: int, t: int, now: int) -> int | None:
        """The step (ns) ``s``'s stamp ``t_ns`` (``t`` on the run's clock, the IMU's time
        ``now``) confirms, 0 for none, None while it is held out as a candidate.

        A step is a stamp lagging the IMU's time by more than ``STEP_BACK_S`` more than the
        stream's stamps did, and either back before the stream's last stamp or, for a regular
        stream slower than its step (a 0.5 Hz GPS back 1.5 s), more than ``STEP_BACK_S`` short
        of its spacing after it, as much as its lag grew (a delivery delay or a stalled
        pipeline keeps the spacing: not a step); confirmed by the stream's next stamp lagging
        alike after the IMU's time went on (stale messages re-sent in a burst come with none
        between them), while the IMU's own clock is not stepping; a step of more than
        ``STEP_BACK_S`` only."""
        assert s.last_ns is not None
        lags = _lag_values(s)
        before = _median(lags)
        assert before is not None
        lag = now - t
        growth = lag - before
        # how much the stream's lags vary when nothing happens (an IMU fed in batches), at
        # most half a step (a stalled pipeline's backlog spreads them by seconds)
        agree = min(max(LAG_AGREE_MIN_NS, _spread(lags)), self._step_ns // 2)
        spacing = _median(s.spacings_ns) or 0
        regular = _spread(s.spacings_ns) <= max(LAG_AGREE_MIN_NS, spacing // 10)
        c = s.candidate
        if growth <= self._step_ns:
            s.candidate = None
            return 0
        if c is not None and t_ns > c[0]:
            if now == c[2]:
                return None  # no IMU sample between: a burst, not yet a confirmation
            if abs(lag - c[1]) <= agree and self._candidate_ns is None:
                s.candidate = None
                # A regular stream's first stamp after the step was due one spacing after its
                # last; others (irregular keyframes, a user's probe) go on lagging the IMU's
                # time as before the step.
                by_lag = (c[1] + lag) // 2 - before
                by_spacing = s.last_ns + spacing - c[3]
                step = by_spacing if regular and abs(by_spacing - by_lag) <= agree else by_lag
                return step if step > self._step_ns else 0
        # The stamp's shortfall from the stream's spacing, for a regular stream.
        shortfall = spacing - (t - s.last_ns)
        if t < s.last_ns or (regular and shortfall > self._step_ns
                             and abs(shortfall - growth) <= agree):  # fmt: skip
            s.candidate = (t_ns, lag, now, t)
            return None
        s.candidate = None
        return 0

    def _record(self, stream: str, last_ns: int, step_ns: int) -> dict[str, float | str]:
        """The report's entry (appended to ``steps``) of ``stream``'s step of ``step_ns`` after
        its stamp ``last_ns`` (run clock)."""
        origin = self._origin_ns if self._origin_ns is not None else last_ns
        entry: dict[str, float | str] = {"stream": stream,
                                         "at_s": round((last_ns - origin) * 1e-9, 6),
                                         "back_s": round(step_ns * 1e-9, 9)}  # fmt: skip
        self.steps.append(entry)
        return entry

    def _reconcile(self, step_ns: int, now_ns: int) -> None:
        """Undo a stream's step that the IMU's step of ``step_ns`` now explains (every clock
        stepped, the stream's stamps fed ahead of the IMU's: reported twice, once as that
        stream's alone, a user's probe)."""
        for name, s in self._streams.items():
            if s.last_step is None:
                continue
            size, at_ns, entry = s.last_step
            if now_ns - at_ns <= RECONCILE_NS and abs(size - step_ns) <= self._step_ns // 2:
                s.shift_ns -= size
                s.last_step = None
                self.steps.remove(entry)
                log.info("the %s clock's step was the IMU's: one step", name)

    def _nearest(self, t_ns: int) -> int:
        """``t_ns`` with whichever IMU shift seen so far puts it nearest the IMU's time."""
        if len(self._shifts) == 1 or self._imu_now_ns is None:
            return t_ns
        now = self._imu_now_ns
        return min((t_ns + s for s in self._shifts), key=lambda t: abs(t - now))
