"""A clock stepping back mid-run (a driver restart, an NTP step): stamps carried across it."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.navigation.clock_steps import ClockSteps
from svains.navigation.navigator import Navigator
from svains.navigation.options import InitOptions, RunConfig
from svains.replay.replay import (
    feed,
    groundtruth_start,
    measurements,
    resolve_config,
    rig_from_dataset,
)

S = 1_000_000_000


def test_imu_stamps_go_on_from_the_last_sample_and_others_take_the_nearest_shift() -> None:
    clock = ClockSteps()
    period = 5_000_000
    last = None
    out = []
    for t in (100 * S, 100 * S + period, 90 * S + 2 * period, 90 * S + 3 * period,
              90 * S + 4 * period):
        t_run = clock.imu(t, last, lambda: period, 100 * S)
        out.append(t_run)
        last = max(last or t_run, t_run)
    # The first sample far back is held out (the caller drops it) until the next confirms the
    # step; the confirmed one goes on from the last sample.
    assert out == [100 * S, 100 * S + period, 90 * S + 2 * period, 100 * S + 3 * period,
                   100 * S + 4 * period]
    (step,) = clock.steps
    assert step["stream"] == "imu"
    assert step["at_s"] == pytest.approx(0.005) and step["back_s"] == pytest.approx(10.0)
    # A single stale sample far back, then the clock going on: no step.
    lone = ClockSteps()
    assert lone.imu(100 * S, None, lambda: period, 100 * S) == 100 * S
    assert lone.imu(90 * S, 100 * S, lambda: period, 100 * S) == 90 * S
    assert lone.imu(100 * S + period, 100 * S, lambda: period, 100 * S) == 100 * S + period
    assert lone.imu(90 * S + period, 100 * S + period, lambda: period, 100 * S) == 90 * S + period
    assert lone.steps == []
    # A frame stamped before the step and delivered late keeps its stamp; one stamped after it
    # on the stepped clock is carried like the IMU.
    assert clock.other(100 * S + period, "frame") == 100 * S + period
    assert clock.other(90 * S + 4 * period, "gps") == 100 * S + 4 * period
    # A step back within STEP_BACK_S is an out-of-order sample: left for the caller to drop.
    late = clock.imu(90 * S + 2 * period, 100 * S + 3 * period, lambda: period, 100 * S)
    assert late == 100 * S + 2 * period
    assert len(clock.steps) == 1


def test_a_stream_whose_clock_alone_steps_back_goes_on_from_its_last_stamp() -> None:
    """A camera driver restarted while the IMU's clock went on: every later frame was late,
    dropped one by one, and the run went on as a pure INS (a user's probe: 151 m)."""
    clock = ClockSteps()
    period, frame = 5_000_000, 200_000_000
    imu_t = 100 * S
    clock.imu(imu_t, None, lambda: period, 100 * S)

    def imu_to(t_ns: int) -> None:
        nonlocal imu_t
        while imu_t + period <= t_ns:
            imu_t = clock.imu(imu_t + period, imu_t, lambda: period, 100 * S)

    out = []
    for raw in [100 * S + k * frame for k in range(1, 6)] + [
            95 * S + k * frame for k in range(6, 9)]:  # fmt: skip
        imu_to(raw if raw >= 100 * S else raw + 5 * S)  # fed as stamped by the IMU clock
        out.append(clock.other(raw, "frame"))
    # The first frame far back is held out (left for the queue to drop as late) until the next
    # confirms the step; from then the frames go on one spacing after the last.
    assert out[:6] == [100 * S + k * frame for k in range(1, 6)] + [95 * S + 6 * frame]
    assert out[6:] == [100 * S + 7 * frame, 100 * S + 8 * frame]
    (step,) = clock.steps
    assert step["stream"] == "frame" and step["back_s"] == pytest.approx(5.0)
    # another stream on the IMU's clock is untouched
    assert clock.other(imu_t, "gps") == imu_t
    # A single stale frame far back, then the stream going on: no step.
    assert clock.other(90 * S, "frame") == 95 * S  # the stream's shift, 5 s back: late
    assert clock.other(95 * S + 9 * frame, "frame") == 100 * S + 9 * frame
    assert len(clock.steps) == 1
    # Far back from its last but not behind the IMU's time (frames fed ahead, then one from
    # before): no step.
    ahead = ClockSteps()
    ahead.imu(100 * S, None, lambda: period, 100 * S)
    ahead.other(103 * S, "frame")
    ahead.other(100 * S + frame, "frame")
    assert ahead.other(100 * S + 2 * frame, "frame") == 100 * S + 2 * frame
    assert ahead.steps == []


def _run(ds, config, step_at_s: float | None, back_s: float = 5.0,
         streams: tuple[int, ...] | None = None):
    init = groundtruth_start(ds, config, None)
    nav = Navigator(config, rig_from_dataset(ds), initial_state=init)
    t0 = init.t_ns
    for t, kind, payload in measurements(ds, config, t0):
        if step_at_s is not None and t > t0 + step_at_s * S and (
                streams is None or kind in streams):  # fmt: skip
            t -= round(back_s * S)
        feed(nav, kind, t, payload)
    return nav.close()


def test_every_stream_stepped_back_mid_run_gives_the_clean_run(
    village_30s: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """All clocks back 5 s at 15 s: before, the next 5 s of samples were dropped one by one,
    vision was then refused as a jump and the run diverged (a user's probe: 514 m)."""
    ds = load_dataset(village_30s)
    config = resolve_config(ds, RunConfig(method="3d", use_gps=False, duration_s=25.0,
                                               init=InitOptions(mode="groundtruth")))
    clean = _run(ds, config, None)
    with caplog.at_level(logging.WARNING):
        stepped = _run(ds, config, 15.0)
    steps = [r.getMessage() for r in caplog.records if "clock stepped back" in r.getMessage()]
    assert len(steps) == 1 and "stepped back 5.000 s" in steps[0]
    (step,) = stepped.report["clock_steps"]
    assert step["at_s"] == pytest.approx(15.0, abs=0.02)
    assert step["back_s"] == pytest.approx(5.0, abs=1e-6)  # the step itself, not less a period
    # The first IMU sample and the magnetometer samples stamped on the stepped clock that came
    # before the IMU's next sample confirmed the step: dropped, the only measurements lost.
    assert clean.report.get("dropped") is None
    assert stepped.report["dropped"] == {"imu": 1, "mag": 2}
    assert stepped.report["vision"]["frames_fused"] == clean.report["vision"]["frames_fused"]
    np.testing.assert_array_equal(stepped.t_ns, clean.t_ns)
    err = np.linalg.norm(stepped.x[:, :3] - clean.x[:, :3], axis=1)
    assert err.max() < 0.01


def test_the_camera_clock_alone_stepped_back_mid_run_gives_the_clean_run(
    village_30s: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The camera's clock back 5 s at 15 s, the IMU's steady: every later frame was dropped as
    late, the run went on as a pure INS (a user's probe: 151 m on EuRoC)."""
    ds = load_dataset(village_30s)
    config = resolve_config(ds, RunConfig(method="3d", use_gps=False, duration_s=25.0,
                                          init=InitOptions(mode="groundtruth")))
    frame_kind = 3  # replay's stream order: GPS, MAG, SONAR, FRAME, IMU
    init = groundtruth_start(ds, config, None)
    nav = Navigator(config, rig_from_dataset(ds), initial_state=init)
    lost = min(t for t, kind, _ in measurements(ds, config, init.t_ns)
               if kind == frame_kind and t > init.t_ns + 15 * S)  # fmt: skip
    for t, kind, payload in measurements(ds, config, init.t_ns):
        if not (kind == frame_kind and t == lost):
            feed(nav, kind, t, payload)
    clean = nav.close()  # but for the frame the step costs
    with caplog.at_level(logging.WARNING):
        stepped = _run(ds, config, 15.0, streams=(frame_kind,))
    steps = [r.getMessage() for r in caplog.records if "clock stepped back" in r.getMessage()]
    assert len(steps) == 1 and "the frame clock stepped back 5.000 s while the IMU's went on" \
        in steps[0]
    (step,) = stepped.report["clock_steps"]
    assert step["stream"] == "frame" and step["at_s"] == pytest.approx(15.0, abs=0.3)
    # the first frame of the new clock is lost (held out until the next confirms the step)
    assert stepped.report["dropped"] == {"frame": 1}
    assert stepped.report["vision"]["frames_fused"] == clean.report["vision"]["frames_fused"]
    np.testing.assert_array_equal(stepped.t_ns, clean.t_ns)
    np.testing.assert_allclose(stepped.x, clean.x, atol=1e-9)


def _feed(events: list[tuple[str, int]]) -> tuple[ClockSteps, list[tuple[str, int, int]]]:
    """``events``: ("imu", raw) or (stream, raw) in the order a driver feeds them; the other
    streams' (stream, raw, run-clock) stamps."""
    clock, last, out = ClockSteps(), None, []
    for kind, raw in events:
        if kind == "imu":
            t = clock.imu(raw, last, lambda: 5_000_000, 100 * S)
            last = t if last is None or t > last else last
        else:
            out.append((kind, raw, clock.other(raw, kind)))
    return clock, out


def _imu(t_from: int, t_to: int, step_back: int = 0, after: int | None = None
         ) -> list[tuple[str, int]]:  # fmt: skip
    return [("imu", t - (step_back if after is not None and t > after else 0))
            for t in range(t_from, t_to, 5_000_000)]


def _stale_burst(stream: str, spacing: int, n: int) -> list[tuple[str, int]]:
    """``n`` stamps of ``stream`` ``spacing`` ns apart, fed as they come between 200 Hz IMU
    samples, with two stale ones from 10 s before re-sent back to back halfway."""
    ev: list[tuple[str, int]] = []
    imu_t = 100 * S
    for k in range(n):
        t = 100 * S + k * spacing
        while imu_t <= t:
            ev.append(("imu", imu_t))
            imu_t += 5_000_000
        if k == n // 2:
            ev += [(stream, t - 10 * S), (stream, t - 10 * S + spacing)]
        ev.append((stream, t))
    return ev


def test_a_stream_step_little_over_a_second_is_taken_and_stale_messages_are_not() -> None:
    """A user's probe: a 1 Hz GPS stepping back 1.5 s and frames fed 0.3 s ahead of the IMU
    stepping back 1.2 s were missed (every later stamp late), two stale frames re-sent from 10 s
    before were taken for a step (the stream 10 s ahead from then), and every clock stepping
    with frames fed ahead of the IMU was reported twice."""
    frame = 50_000_000
    # (a) GPS 1 Hz, its clock alone back 1.5 s after 110 s
    ev: list[tuple[str, int]] = []
    for k in range(21):
        t = 100 * S + k * S
        ev += _imu(t - S + 5_000_000 if k else t, t + 5_000_000)
        ev.append(("gps", t if t <= 110 * S else t - 1_500_000_000))
    clock, out = _feed(ev)
    assert [(s["stream"], s["back_s"]) for s in clock.steps] == [("gps", pytest.approx(1.5))]
    assert [t_run - (100 * S + k * S) for k, (_, _, t_run) in enumerate(out)][12:] == [0] * 9
    # (b) frames fed 0.3 s ahead of the IMU, their clock alone back 1.2 s after 105 s
    ev, imu_t = [], 100 * S
    for k in range(200):
        tf = 100 * S + k * frame
        while imu_t <= tf - 300_000_000:
            ev.append(("imu", imu_t))
            imu_t += 5_000_000
        ev.append(("frame", tf if tf <= 105 * S else tf - 1_200_000_000))
    clock, out = _feed(ev)
    assert [(s["stream"], s["back_s"]) for s in clock.steps] == [("frame", pytest.approx(1.2))]
    assert {t_run - (100 * S + k * frame) for k, (_, _, t_run) in enumerate(out)
            if k > 110} == {0}  # fmt: skip
    # (c) two stale frames 10 s old re-sent in a burst, the stream otherwise steady
    clock, out = _feed(_stale_burst("frame", frame, 200))
    assert clock.steps == []
    assert {t_run - raw for _, raw, t_run in out[105:]} == {0}
    # (d) every clock back 10 s after 105 s, frames fed 0.2 s ahead of the IMU: one step
    ev, imu_t = [], 100 * S
    for k in range(200):
        tf = 100 * S + k * frame
        while imu_t <= tf - 200_000_000:
            ev.append(("imu", imu_t if imu_t <= 105 * S else imu_t - 10 * S))
            imu_t += 5_000_000
        ev.append(("frame", tf if tf <= 105 * S else tf - 10 * S))
    clock, out = _feed(ev)
    assert [(s["stream"], s["back_s"]) for s in clock.steps] == [("imu", pytest.approx(10.0))]
    assert {t_run - (100 * S + k * frame) for k, (_, _, t_run) in enumerate(out)
            if k > 110} == {0}  # fmt: skip


def test_no_step_after_an_imu_dropout_and_none_for_a_fast_stream_stale_burst() -> None:
    """A reviewer's cases: frames fed in order across a 2 s IMU dropout with one pair swapped
    after it were taken for a 1.75 s step (their lags were measured while the IMU's time stood
    still); two stale samples of a 100 Hz magnetometer re-sent back to back (their lags one
    10 ms spacing apart) were taken for a 10 s step."""
    frame, mag = 50_000_000, 10_000_000
    for swap in (120, 121, 122, 123):
        ev: list[tuple[str, int]] = []
        imu_t = 100 * S
        order = list(range(200))
        order[swap], order[swap + 1] = order[swap + 1], order[swap]
        for k in order:
            tf = 100 * S + k * frame
            while imu_t <= tf:
                if not 104 * S < imu_t < 106 * S:
                    ev.append(("imu", imu_t))
                imu_t += 5_000_000
            ev.append(("frame", tf))
        clock, out = _feed(ev)
        assert clock.steps == [] and {t_run - raw for _, raw, t_run in out} == {0}
    clock, out = _feed(_stale_burst("mag", mag, 600))
    assert clock.steps == [] and {t_run - raw for _, raw, t_run in out[305:]} == {0}


@pytest.mark.parametrize("camera_in_gap", [False, True])
def test_a_camera_clock_step_inside_an_imu_dropout_is_carried(camera_in_gap: bool) -> None:
    """A review's case, a USB reset: the IMU drops out 104-106 s and the camera's driver
    restarts in it, its clock 5 s back from 105 s on (frames still coming in the gap, or none).
    Every lag was forgotten at the gap, so the stepped stamps became the new normal: no step,
    every later frame 5 s behind the IMU, dropped as late. The lags from before the gap
    still tell the stream's clock."""
    frame = 50_000_000
    ev: list[tuple[str, int]] = []
    imu_t = 100 * S
    for k in range(300):
        tf = 100 * S + k * frame
        while imu_t <= tf:
            if not 104 * S < imu_t < 106 * S:
                ev.append(("imu", imu_t))
            imu_t += 5_000_000
        if camera_in_gap or not 104 * S < tf < 106 * S:
            ev.append(("frame", tf if tf <= 105 * S else tf - 5 * S))
    clock, out = _feed(ev)
    assert [st["back_s"] for st in clock.steps] == [5.0]
    stepped = [(raw, t) for _, raw, t in out if raw + 5 * S >= 106 * S and raw < 104 * S
               and t != raw]  # fmt: skip
    # every stepped frame after the gap but the one held until the next confirmed the step
    assert len(stepped) == 59 and all(t == raw + 5 * S for raw, t in stepped)


@pytest.mark.parametrize(("spacing_s", "back_s"), [(2.0, 1.5), (7.0, 5.0)])
def test_a_slow_stream_stepping_back_less_than_its_spacing(spacing_s: float,
                                                           back_s: float) -> None:
    """A 0.5 Hz GPS back 1.5 s, frames 7 s apart back 5 s: never before their last stamp, they
    were missed and every later stamp lagged by the step (dropped as late). A delivery delay of
    the same size (stamps right, spacing kept) is not a step."""
    spacing, back = round(spacing_s * S), round(back_s * S)
    for delayed in (False, True):
        # (feed time, event): the IMU every 5 ms, each GPS stamp when it is delivered
        timed = [(t, ("imu", t)) for t in range(100 * S, 100 * S + 16 * spacing, 5_000_000)]
        for k in range(15):
            t = 100 * S + k * spacing
            if delayed:  # delivered `back` late from the 8th stamp on, stamped right
                timed.append((t + (back if k > 6 else 0) + 1, ("gps", t)))
            else:
                timed.append((t + 1, ("gps", t if k <= 6 else t - back)))
        ev = [e for _, e in sorted(timed)]
        clock, out = _feed(ev)
        if delayed:
            assert clock.steps == [] and {t_run - raw for _, raw, t_run in out} == {0}
        else:
            assert [(s["stream"], s["back_s"]) for s in clock.steps] == [
                ("gps", pytest.approx(back_s))]
            # the first stamp after the step is held out (dropped as late), the rest carried
            assert [t_run - (100 * S + k * spacing) for k, (_, _, t_run) in enumerate(out)
                    if k != 7] == [0] * 14  # fmt: skip


def test_a_camera_step_found_with_the_imu_fed_in_batches() -> None:
    """The camera's clock alone back 5 s, frames at 20 Hz, the IMU delivered in 100 ms batches
    (a batching driver): consecutive frames' lags differ by a spacing, and the step was never
    confirmed (every later frame dropped as late)."""
    frame = 50_000_000
    for batch in (50_000_000, 100_000_000):
        ev: list[tuple[str, int]] = []
        imu_t = 100 * S
        for k in range(300):
            tf = 100 * S + k * frame
            while imu_t <= (tf - 100 * S) // batch * batch + 100 * S:
                ev.append(("imu", imu_t))
                imu_t += 5_000_000
            ev.append(("frame", tf if tf <= 105 * S else tf - 5 * S))
        clock, out = _feed(ev)
        assert [(s["stream"], s["back_s"]) for s in clock.steps] == [
            ("frame", pytest.approx(5.0))]
        assert {t_run - (100 * S + k * frame) for k, (_, _, t_run) in enumerate(out)
                if k > 102} == {0}  # fmt: skip


@pytest.mark.parametrize(("imu_at_s", "imu_back_s", "steps"), [
    (105.2, 5.0, [("imu", 5.0)]),  # every clock stepped, frames first: one step
    (112.0, 5.0, [("frame", 5.0), ("imu", 5.0)]),  # 7 s later: the IMU's own
    (105.2, 2.0, [("frame", 5.0), ("imu", 2.0)]),  # another size: the IMU's own
])
def test_a_stream_step_the_imu_step_explains_is_undone_only_then(
        imu_at_s: float, imu_back_s: float, steps: list[tuple[str, float]]) -> None:
    frame = 50_000_000
    imu_at, imu_back = round(imu_at_s * S), round(imu_back_s * S)
    timed = [(t, ("imu", t if t <= imu_at else t - imu_back))
             for t in range(100 * S, 120 * S, 5_000_000)]
    timed += [(t + 1, ("frame", t if t <= 105 * S else t - 5 * S))
              for t in range(100 * S, 120 * S, frame)]
    clock, _ = _feed([e for _, e in sorted(timed)])
    assert [(s["stream"], s["back_s"]) for s in clock.steps] == [
        (name, pytest.approx(back)) for name, back in steps]


@pytest.mark.parametrize("lost", [0, 1, 3, 6])
def test_a_stalled_pipeline_delivering_its_backlog_is_no_step(lost: int) -> None:
    """A reviewer's case: a 20 Hz camera delivered 0.3 s late, its pipeline stalled 2 s (the
    next ``lost`` frames lost), then the backlog in a burst 5 ms apart: taken for steps of
    -50 to -300 ms (the burst's lags passed as agreeing, the lost frames' span as the step),
    every later frame shifted. Stamps right, delivered late: nothing to shift."""
    ms = 1_000_000
    timed = [(t, ("imu", t)) for t in range(100 * S, 116 * S, 5 * ms)]
    delivered = 0
    for k in range(1, 300):
        if 61 <= k < 61 + lost:
            continue
        raw = 100 * S + k * 50 * ms
        delivered = max(delivered + (2000 * ms if k == 60 else 5 * ms), raw + 300 * ms)
        timed.append((delivered + 1, ("frame", raw)))
    clock, out = _feed([e for _, e in sorted(timed)])
    assert clock.steps == [] and {t_run - raw for _, raw, t_run in out} == {0}
