"""``vision_gap_report``: the report keys that say when vision stopped."""

from __future__ import annotations

import numpy as np
import pytest

from svains.navigation.vision_gaps import vision_gap_report

S = 1_000_000_000


def test_vision_that_stops_early_is_reported_as_a_gap() -> None:
    # 20 s run; frames fused at 2 Hz over the first 4.5 s only (the images-cover-4.7-s
    # case): one gap from 4.5 s to the end.
    fused = np.arange(0, 5 * S, S // 2)[:10]
    rep = vision_gap_report(fused, 0, 20 * S, max_gap_s=2.0)
    assert rep["vision_gaps"] == [{"start_s": 4.5, "duration_s": 15.5}]
    assert rep["vision_longest_gap_s"] == pytest.approx(15.5)
    assert rep["vision_gap_fraction"] == pytest.approx(15.5 / 20)
    assert rep["vision_fused_frames"] == 10 and rep["vision_degraded"] is False


def test_regular_vision_has_no_gap_and_none_at_all_is_degraded() -> None:
    fused = np.arange(S, 30 * S, S // 2)
    rep = vision_gap_report(fused, S, 29 * S + S // 2)
    assert rep["vision_gaps"] == [] and rep["vision_gap_fraction"] == 0.0
    assert rep["vision_longest_gap_s"] == pytest.approx(0.5)
    none = vision_gap_report(np.zeros(0, np.int64), 0, 10 * S)
    assert none["vision_degraded"] is True and none["vision_gap_fraction"] == 1.0
    assert none["vision_gaps"] == [{"start_s": 0.0, "duration_s": 10.0}]


def test_a_gap_in_the_middle_and_times_outside_the_run() -> None:
    fused = np.array([-5, 0, 1, 2, 8, 9, 10, 50], dtype=np.int64) * S
    rep = vision_gap_report(fused, 0, 10 * S, max_gap_s=3.0)
    assert rep["vision_gaps"] == [{"start_s": 2.0, "duration_s": 6.0}]
    assert rep["vision_fused_frames"] == 6
    with pytest.raises(ValueError, match="before it starts"):
        vision_gap_report(fused, 10 * S, 0)


def test_the_gap_limit_follows_the_streams_longer_spacings() -> None:
    from svains.navigation.vision_gaps import vision_gap_limit_s

    assert vision_gap_limit_s([], 2.0) == 2.0
    assert vision_gap_limit_s([S // 5] * 31, 2.0) == 2.0  # 5 Hz: the floor
    assert vision_gap_limit_s([5 * S] * 31, 2.0) == pytest.approx(12.5)  # every 25th frame
    # Alternating 0.2 s / 5 s (a user's probe): the same limit with 15 or 16 long spacings in
    # the window (the median flipped between 0.2 and 2.6 s: 2 s, then 6.5 s)
    for n_long in (15, 16):
        spacings = [S // 5] * (31 - n_long) + [5 * S] * n_long
        assert vision_gap_limit_s(spacings, 2.0) == pytest.approx(12.5)
