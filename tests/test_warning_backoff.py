"""``RateLimitedLog``: a fault that lasts is said at doubling intervals, a new one at once."""

from __future__ import annotations

import itertools
import logging

import pytest

from svains.navigation.fault_handling import MAX_BACKOFF, RateLimitedLog

S = 1_000_000_000


def _lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_a_lasting_fault_is_said_at_doubling_intervals_then_a_new_one_at_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A GPS jump to the end of a run said its line every second (20 lines; a saturating IMU
    129: a user's probe)."""
    log = RateLimitedLog(1.0)
    log.origin_ns = 0
    with caplog.at_level("WARNING"):
        for k in range(40):
            log.warn("gps-jump", k * S, "gps jumped")
        log.warn("imu-gap", 5 * S, "imu gap")  # another kind keeps its own pace
        for k in range(60, 63):  # quiet for 20 s: a new episode, said at once
            log.warn("gps-jump", k * S, "gps jumped again")
    lines = _lines(caplog)
    jumps = [ln for ln in lines if "gps jumped" in ln]
    assert [ln.split(" s into")[0] for ln in jumps] == ["0.000", "1.000", "3.000", "7.000",
                                                       "15.000", "31.000", "60.000", "61.000"]
    assert jumps[5].endswith("(15 more since the last warning)")
    assert jumps[6].endswith("gps jumped again (8 more since the last warning)")
    assert sum("imu gap" in ln for ln in lines) == 1


def test_the_interval_stops_growing_at_the_cap(caplog: pytest.LogCaptureFixture) -> None:
    log = RateLimitedLog(1.0)
    with caplog.at_level("WARNING"):
        for k in range(0, 600):
            log.warn("x", k * S, "x")
    times = [float(ln.split("t=")[1].split(" s")[0]) for ln in _lines(caplog)]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) == MAX_BACKOFF and gaps[-1] == MAX_BACKOFF
