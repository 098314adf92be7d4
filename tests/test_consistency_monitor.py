"""``ConsistencyMonitor``: rejections across sensors ask for inflation, then a reset."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from svains.navigation.consistency import ConsistencyMonitor, ConsistencyOptions

S = 1_000_000_000  # ns per second


def _feed(m: ConsistencyMonitor, sensor: str, outcomes: str, t0_s: float, dt_s: float) -> int:
    """``outcomes`` 'a' accepted / 'r' rejected, one per update; returns the last time (ns)."""
    t = int(t0_s * S)
    for k, c in enumerate(outcomes):
        t = int((t0_s + k * dt_s) * S)
        m.observe(sensor, c == "a", 1.0 if c == "a" else 400.0, 3, t)
    return t


def test_occasional_rejections_ask_for_nothing() -> None:
    m = ConsistencyMonitor()
    t = _feed(m, "gps", "aararraaraa", 0.0, 1.0)
    t = max(t, _feed(m, "mag", "araarraaaar", 0.0, 0.1))
    assert m.rejecting(t) == ()
    assert m.should_recover(t, position_std_m=0.5) is None
    assert m.inflations == 0 and m.resets == 0


def test_two_sensors_rejected_together_inflate_then_reset() -> None:
    m = ConsistencyMonitor()
    _feed(m, "mag", "aaarrr", 0.0, 0.1)
    t = _feed(m, "sonar", "aarrr", 0.1, 0.1)
    assert m.rejecting(t) == ("mag", "sonar")
    first = m.should_recover(t, position_std_m=0.3)
    assert first is not None and first.kind == "inflate"
    assert first.inflate_factor == ConsistencyOptions().inflate_factor
    assert first.sensors == ("mag", "sonar")
    assert m.should_recover(t, 0.3) is None  # the evidence was used up
    # still rejected soon after the inflation: the filter is lost, reset from GPS
    _feed(m, "mag", "rrr", 1.0, 0.1)
    t = _feed(m, "sonar", "rrr", 1.0, 0.1)
    second = m.should_recover(t, 0.3)
    assert second is not None and second.kind == "reset"
    assert m.summary()["inflations"] == 1 and m.summary()["resets"] == 1


def test_gps_alone_is_enough_and_fixes_return_within_five_seconds() -> None:
    # 1 Hz GPS after a fault: three rejected fixes (t = 1, 2, 3 s) trigger the inflation, so
    # the fix at 4 s can be accepted: within the 5 s.
    m = ConsistencyMonitor()
    t = _feed(m, "gps", "arrr", 0.0, 1.0)
    action = m.should_recover(t, position_std_m=0.4)
    assert action is not None and action.kind == "inflate" and t == 3 * S


def test_a_single_non_anchor_sensor_or_a_large_covariance_is_not_lost() -> None:
    m = ConsistencyMonitor()
    t = _feed(m, "mag", "rrrrrr", 0.0, 0.1)
    assert m.should_recover(t, 0.3) is None  # one relative sensor may simply be disturbed
    t = _feed(m, "gps", "rrr", 1.0, 1.0)
    assert m.should_recover(t, position_std_m=50.0) is None  # the gate widens by itself


def test_stale_rejections_do_not_count() -> None:
    m = ConsistencyMonitor()
    _feed(m, "gps", "rrr", 0.0, 1.0)
    assert m.rejecting(20 * S) == ()
    assert m.should_recover(20 * S, 0.3) is None


def test_windowed_nis_per_dof() -> None:
    m = ConsistencyMonitor(ConsistencyOptions(window=4))
    for k, nis in enumerate([30.0, 3.0, 3.0, 6.0, 3.0]):
        m.observe("gps", True, nis, 3, k * S)
    assert m.nis_mean("gps") == pytest.approx((1.0 + 1.0 + 2.0 + 1.0) / 4)
    assert m.nis_mean("mag") is None


def test_relative_sensors_rejecting_while_gps_is_fused_is_not_lost() -> None:
    # clean data, a model error (the paper model's 3d and sonar on the village): GPS still
    # passes its gate, so the filter is anchored and nothing is inflated
    m = ConsistencyMonitor()
    _feed(m, "3d", "arrrr", 0.0, 0.5)
    _feed(m, "sonar", "arrrr", 0.0, 0.1)
    t = _feed(m, "gps", "aaa", 0.0, 1.0)
    assert m.rejecting(t) == ("3d", "sonar") and m.anchored(t)
    assert m.should_recover(t, 0.3) is None
    t = _feed(m, "gps", "r", 3.0, 1.0)  # a rejected fix lifts the veto
    assert not m.anchored(t)
    action = m.should_recover(t, 0.3)
    assert action is not None and action.kind == "inflate"


def test_gps_denied_vision_alone_inflates_and_escalates_to_inflate_again() -> None:
    # Without GPS nothing contradicts a vision method whose frames are refused: three refused
    # frames in a row inflate; with GPS in the run the same rejections alone are not enough.
    m = ConsistencyMonitor(ConsistencyOptions(anchor_in_use=False))
    t = _feed(m, "3d", "arrr", 0.0, 0.5)
    first = m.should_recover(t, position_std_m=0.3)
    assert first is not None and first.kind == "inflate" and first.sensors == ("3d",)
    t = _feed(m, "3d", "rrr", 2.0, 0.5)
    second = m.should_recover(t, position_std_m=0.3)
    assert second is not None and second.kind == "inflate"  # no GPS to reset from
    with_gps = ConsistencyMonitor()
    t = _feed(with_gps, "3d", "arrr", 0.0, 0.5)
    assert with_gps.should_recover(t, position_std_m=0.3) is None
    mag_only = ConsistencyMonitor(ConsistencyOptions(anchor_in_use=False))
    t = _feed(mag_only, "mag", "rrrr", 0.0, 0.1)
    assert mag_only.should_recover(t, position_std_m=0.3) is None  # not a standalone sensor


def _gps(m: ConsistencyMonitor, nis: list[float], t0_s: float, gate: float = 16.3) -> int:
    """1 Hz GPS updates with these NIS values (accepted below ``gate``); the last time (ns)."""
    t = int(t0_s * S)
    for k, v in enumerate(nis):
        t = int((t0_s + k) * S)
        m.observe("gps", v <= gate, v, 3, t, gate)
    return t


def test_a_gps_jump_right_after_an_accepted_fix_is_distrusted_not_adopted() -> None:
    # A 50 m step (NIS ~2500 against a 16.3 gate) one second after a normal fix, the offset
    # constant since: the filter is not lost, GPS is; no inflation, no reset, ever.
    m = ConsistencyMonitor()
    t = _gps(m, [2.0, 3.0, 2500.0, 2450.0, 2400.0, 2380.0, 2300.0, 2200.0], 0.0)
    for _ in range(3):
        action = m.should_recover(t, position_std_m=0.5)
        assert action is not None and action.kind == "distrust" and action.sensors == ("gps",)
    assert m.inflations == 0 and m.resets == 0 and m.summary()["jumps"] == 1
    # accepted again (the step ended): a later slow drift is handled as before
    _gps(m, [3.0], 8.0)
    t = _gps(m, [30.0, 60.0, 90.0], 9.0)
    assert m.should_recover(t, 0.5).kind == "inflate"  # type: ignore[union-attr]


def test_an_offset_that_grows_is_the_filter_drifting_not_a_jump() -> None:
    # An undetected IMU fault: the error grows with time, so the NIS quadruples in a second.
    m = ConsistencyMonitor()
    t = _gps(m, [2.0, 3.0, 400.0, 1600.0, 3600.0], 0.0)
    action = m.should_recover(t, 0.5)
    assert action is not None and action.kind == "inflate"
    assert [e["kind"] for e in m.summary()["events"]] == ["jump", "jump-withdrawn", "inflate"]  # type: ignore[index]


def test_a_jump_after_an_imu_fault_or_with_another_sensor_rejecting_is_the_filters() -> None:
    m = ConsistencyMonitor()
    m.note_imu_fault(int(1.5 * S))  # a gap between the accepted fix and the jump
    t = _gps(m, [2.0, 3.0, 2500.0, 2450.0, 2400.0], 0.0)
    assert m.should_recover(t, 0.5).kind == "inflate"  # type: ignore[union-attr]
    m = ConsistencyMonitor()
    t = _gps(m, [2.0, 3.0, 2500.0, 2450.0, 2400.0], 0.0)
    _feed(m, "3d", "rrrr", 3.5, 0.2)  # vision also refuses the state: lost
    assert m.should_recover(t, 0.5).kind == "inflate"  # type: ignore[union-attr]
    # a mild rejection (below jump_factor times the gate) is no jump either
    m = ConsistencyMonitor()
    t = _gps(m, [2.0, 3.0, 100.0, 100.0, 100.0], 0.0)
    assert m.should_recover(t, 0.5).kind == "inflate"  # type: ignore[union-attr]


def _feed_whitened(m: ConsistencyMonitor, w: list[list[float]], accepted: bool = True) -> int:
    """Accepted (or rejected) GPS updates 1 s apart with whitened innovations ``w``."""
    t = 0
    for k, wk in enumerate(w):
        t = (k + 1) * S
        m.observe("gps", accepted, sum(x * x for x in wk), len(wk), t, 100.0, np.array(wk))
    return t


ON = ConsistencyOptions(bias_probability=0.99)


def test_gps_innovations_that_lean_one_way_raise_a_bias_alarm_once() -> None:
    m = ConsistencyMonitor(ON)
    # 3 * |(2.5, 0, 0)|^2 = 18.75 > 11.34, the 0.99 quantile of chi-square(3)
    t = _feed_whitened(m, [[2.5, 0.0, 0.0]] * 3)
    action = m.biased(t)
    assert action is not None and action.kind == "bias" and action.sensors == ("gps",)
    assert "18.8 > 11.3, 3 dof" in action.reason
    assert action.window_s == 2.0  # three fixes 1 s apart
    assert m.biased(t) is None  # the evidence is used up
    assert m.summary()["bias_shifts"] == 1
    assert m.summary()["events"] == [{"t_ns": t, "kind": "bias", "sensors": ["gps"]}]


def test_large_innovations_of_changing_sign_rejected_ones_and_short_windows_are_no_bias() -> None:
    m = ConsistencyMonitor(ON)
    t = _feed_whitened(m, [[2.5, 0.0, 0.0], [-2.5, 0.0, 0.0], [2.5, 0.0, 0.0]])
    assert m.biased(t) is None  # mean 0.83: 3 * 0.69 = 2.1
    m = ConsistencyMonitor(ON)
    t = _feed_whitened(m, [[3.0, 0.0, 0.0]] * 3, accepted=False)  # a jump's or a lost filter's
    assert m.biased(t) is None
    m = ConsistencyMonitor(ON)
    t = _feed_whitened(m, [[3.0, 0.0, 0.0]] * 2)
    assert m.biased(t) is None
    m = ConsistencyMonitor()  # off by default
    t = _feed_whitened(m, [[3.0, 0.0, 0.0]] * 3)
    assert m.biased(t) is None


def test_a_change_of_dimension_restarts_the_window_and_a_recovery_clears_it() -> None:
    m = ConsistencyMonitor(ON)
    _feed_whitened(m, [[3.0, 0.0, 0.0, 0.0, 0.0, 0.0]] * 2)
    t = _feed_whitened(m, [[3.0, 0.0, 0.0]])  # a fix without velocity
    assert m.biased(t) is None
    t = _feed_whitened(m, [[3.0, 0.0, 0.0]] * 3)
    m.clear_bias_evidence()
    assert m.biased(t) is None


def test_a_gps_window_leaning_in_position_alone_is_no_imu_bias() -> None:
    # An IMU bias step moves the GPS velocity innovation at once; a position that leans while
    # the velocity agrees is the receiver running off (a slow ramp), not the IMU.
    cov = np.diag([4.0, 4.0, 4.0, 0.01, 0.01, 0.01])  # 2 m and 0.1 m/s

    def window(velocity_mps: float) -> ConsistencyMonitor:
        m = ConsistencyMonitor(replace(ON, bias_rate_probability=0.9))
        for k in range(3):
            r = np.array([5.0, 0.0, 0.0, velocity_mps, 0.0, 0.0])  # 2.5 sigma in x
            w = r / np.sqrt(np.diag(cov))
            m.observe("gps", True, float(w @ w), 6, (k + 1) * S, 100.0, w, r, cov)
        return m

    # position 3 * 2.5^2 = 18.75 > 16.8 (0.99, 6 dof); velocity 0.05 m/s: 3 * 0.25 = 0.75
    assert window(0.05).biased(3 * S) is None
    # velocity 0.15 m/s: 3 * 2.25 = 6.75 > 6.25 (0.9, 3 dof): both lean, the IMU
    assert window(0.15).biased(3 * S) is not None
    # the condition off (the default): the position alone alarms
    m = ConsistencyMonitor(ON)
    for k in range(3):
        r = np.array([5.0, 0.0, 0.0, 0.05, 0.0, 0.0])
        w = r / np.sqrt(np.diag(cov))
        m.observe("gps", True, float(w @ w), 6, (k + 1) * S, 100.0, w, r, cov)
    assert m.biased(3 * S) is not None


def test_white_innovations_raise_the_alarm_at_its_false_alarm_rate() -> None:
    rng = np.random.default_rng(0)
    alarms, windows = 0, 3000
    m = ConsistencyMonitor(ON)
    for k in range(windows):
        for j in range(3):
            w = rng.standard_normal(6)
            m.observe("gps", True, float(w @ w), 6, (3 * k + j) * S, 100.0, w)
        alarms += m.biased((3 * k + 2) * S) is not None
        m.clear_bias_evidence()
    assert 0.005 < alarms / windows < 0.016, alarms  # 1 % expected (30 +- 11 at 2 sigma)


def _observe_at(m: ConsistencyMonitor, times_s: list[float], w: list[float]) -> int:
    """Accepted GPS updates at ``times_s`` with the same whitened innovation ``w``."""
    for t_s in times_s:
        m.observe("gps", True, sum(x * x for x in w), len(w), int(t_s * S), 100.0, np.array(w))
    return int(times_s[-1] * S)


def test_a_bias_window_never_spans_an_outage_but_a_slow_sensor_keeps_its_windows() -> None:
    lean = [2.5, 0.0, 0.0]  # 3 * 6.25 = 18.75 > 11.34: an alarm over any 3 of them
    m = ConsistencyMonitor(ON)
    # 1 Hz fixes, then a 10 s outage: the two fixes after it are no window with the one before
    t = _observe_at(m, [1.0, 2.0, 13.0, 14.0], lean)
    assert m.biased(t) is None
    t = _observe_at(m, [15.0], lean)  # the third fix after the outage completes a window
    action = m.biased(t)
    assert action is not None and action.window_s == 2.0
    # a sensor at 0.2 Hz: once its spacing is known, 5 s is its rhythm, not an outage
    m = ConsistencyMonitor(ON)
    t = _observe_at(m, [5.0, 10.0, 15.0], lean)
    assert m.biased(t) is None  # the first spacing, unknown before, broke the window once
    t = _observe_at(m, [20.0], lean)
    action = m.biased(t)
    assert action is not None and action.window_s == 10.0
    # ... but a 20 s silence in it is one
    t = _observe_at(m, [25.0, 30.0, 50.0, 55.0], lean)
    assert m.biased(t) is None


def test_vision_corrections_take_their_own_window_and_quantile() -> None:
    o = ConsistencyOptions(bias_probability=0.975, bias_sensors=("gps", "3d"),
                           vision_bias_window=4, vision_bias_probability=0.999)  # fmt: skip

    def frames(n: int, lean: float) -> ConsistencyMonitor:
        m = ConsistencyMonitor(o)
        w = np.array([lean, 0.0, 0.0, 0.0, 0.0, 0.0])
        for k in range(n):  # 5 Hz
            m.observe("3d", True, 1.0, 6, (k + 1) * S // 5, whitened=w)
        return m

    # 3 * 2.25^2 = 15.2, beyond GPS's 0.975 quantile (14.4, 6 dof): a vision window holds 4
    assert frames(3, 2.25).biased(3 * S // 5) is None
    assert frames(4, 2.25).biased(4 * S // 5) is None  # 4 * 2.25^2 = 20.3 < 22.5 (0.999)
    action = frames(4, 2.5).biased(4 * S // 5)  # 4 * 2.5^2 = 25
    assert action is not None and action.sensors == ("3d",)
    assert "the last 4 3d corrections share an offset (chi-square 25 > 22.5, 6" in action.reason
    assert action.window_s == pytest.approx(0.6)


def test_a_jump_offset_is_held_until_an_accepted_fix_or_the_hold_ends() -> None:
    """``jump_offsets``: the innovation of a GPS jump's first update, while the jump lasts and
    for at most ``jump_hold_s``; gone once a fix is accepted, and with the hold off."""
    d = np.array([50.0, 0.0, 0.0])
    m = ConsistencyMonitor(ConsistencyOptions(jump_hold_s=20.0))
    m.observe("gps", True, 2.0, 3, 0, 16.3, residual=np.zeros(3))
    m.observe("gps", False, 2500.0, 3, 1 * S, 16.3, residual=d)
    m.observe("gps", False, 2400.0, 3, 2 * S, 16.3, residual=d)
    assert set(m.jump_offsets(2 * S)) == {"gps"}
    np.testing.assert_array_equal(m.jump_offsets(2 * S)["gps"], d)
    assert m.jump_offsets(21 * S + 1) == {}  # past the hold: the gate alone decides
    m.observe("gps", True, 3.0, 3, 5 * S, 16.3, residual=np.ones(3))
    assert m.jump_offsets(6 * S) == {}  # the sensor agrees again
    off = ConsistencyMonitor(ConsistencyOptions(jump_hold_s=None))
    off.observe("gps", True, 2.0, 3, 0, 16.3, residual=np.zeros(3))
    off.observe("gps", False, 2500.0, 3, 1 * S, 16.3, residual=d)
    assert off.jump_offsets(2 * S) == {} and off.summary()["jumps"] == 1
    # a rejection that is no jump (a drifting filter) holds no offset
    drift = ConsistencyMonitor()
    _gps(drift, [2.0, 3.0, 400.0, 1600.0], 0.0)
    assert drift.jump_offsets(4 * S) == {}


def test_gps_denied_a_camera_that_jumps_is_distrusted_not_adopted() -> None:
    """GPS-denied, a vision sensor's rejection right after an accepted frame with a NIS far
    beyond its gate and no IMU fault is a jump of the camera (frozen, blocked: KITTI raw with
    3 s of one scene repeated, 12 m instead of 0.30 m when the inflation let it in): distrust,
    no inflation. After an IMU fault, or with GPS in the run, the rejections are the filter's."""
    def frames(m: ConsistencyMonitor, nis: list[float], gate: float = 600.0) -> int:
        t = 0
        for k, v in enumerate(nis):
            t = int(k * 0.1 * S)
            m.observe("3d", v <= gate, v, 400, t, gate)
        return t

    jumps = [400.0, 420.0, 1.8e4, 1.8e4, 1.8e4, 1.7e4]
    m = ConsistencyMonitor(ConsistencyOptions(anchor_in_use=False))
    action = m.should_recover(frames(m, jumps), position_std_m=0.3)
    assert action is not None and action.kind == "distrust" and action.sensors == ("3d",)
    assert m.inflations == 0 and m.summary()["jumps"] == 1
    # a modest cascade (a filter slightly off after a gap) still inflates
    cascade = ConsistencyMonitor(ConsistencyOptions(anchor_in_use=False))
    action = cascade.should_recover(frames(cascade, [400.0, 420.0, 700.0, 750.0, 800.0]), 0.3)
    assert action is not None and action.kind == "inflate"
    # after an IMU fault the same rejections are the filter's
    faulted = ConsistencyMonitor(ConsistencyOptions(anchor_in_use=False))
    faulted.note_imu_fault(int(0.15 * S))
    action = faulted.should_recover(frames(faulted, jumps), 0.3)
    assert action is not None and action.kind == "inflate"
    # with GPS in the run vision is not tested for jumps (nor does it inflate alone)
    aided = ConsistencyMonitor()
    assert aided.should_recover(frames(aided, jumps), 0.3) is None
    assert aided.summary()["jumps"] == 0


def test_gps_that_scatters_is_distrusted_a_trend_is_a_lost_filter() -> None:
    """Anchor rejections alone make the filter lost only when their innovations, from the
    last accepted one on, follow a trend in time (a drifting filter) once there are
    ``TREND_TERMS + 1`` of them; scattered about no trend (multipath) the sensor is
    distrusted, with or without a jump first; a jump whose innovations grow is withdrawn only
    along a trend. With the test off, three rejections inflate as before."""
    rng = np.random.default_rng(3)
    S_cov = np.eye(3)

    def run(residuals: list[np.ndarray], nis: list[float],
            options: ConsistencyOptions | None = None,
            accepted_residual: np.ndarray | None = np.zeros(3)) -> ConsistencyMonitor:  # noqa: B008  # fmt: skip
        m = ConsistencyMonitor(options or ConsistencyOptions())
        m.observe("gps", True, 2.0, 3, 0, 16.3, accepted_residual, accepted_residual, S_cov)
        for k, (r, v) in enumerate(zip(residuals, nis, strict=True), start=1):
            m.observe("gps", False, v, 3, k * S, 16.3, r, r, S_cov)
        return m

    scattered = [rng.normal(0.0, 25.0, 3) for _ in range(4)]
    trend = [np.array([20.0, 0.0, 0.0]) * k + rng.normal(0.0, 1.0, 3) for k in range(1, 5)]
    # a jump (NIS 400 > 10 x 16.3) whose scattered innovations grow: still the sensor's
    m = run(scattered, [400.0, 1500.0, 300.0, 2500.0])
    action = m.should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust" and m.inflations == 0
    # the same growth along a trend: the filter drifts, lost
    m = run(trend, [400.0, 1600.0, 3600.0, 6400.0])
    action = m.should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "inflate"
    assert "jump-withdrawn" in [e["kind"] for e in m.summary()["events"]]  # type: ignore[index]
    # no jump (NIS under 10 x the gate): the last accepted innovation and three rejected
    # ones tell (the fewest a lost filter waits for); without the accepted one's, a fourth
    modest = [60.0, 170.0, 50.0, 90.0]
    m = run(scattered[:3], modest[:3])
    action = m.should_recover(3 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust" and "scatter" in action.reason
    m = run(trend[:3], modest[:3])
    assert m.should_recover(3 * S, position_std_m=0.5).kind == "inflate"  # type: ignore[union-attr]
    m = run(scattered[:3], modest[:3], accepted_residual=None)
    assert m.should_recover(3 * S, position_std_m=0.5) is None
    m = run(scattered, modest, accepted_residual=None)
    action = m.should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust" and "scatter" in action.reason
    m = run(trend, modest, accepted_residual=None)
    assert m.should_recover(4 * S, position_std_m=0.5).kind == "inflate"  # type: ignore[union-attr]
    # the test off: three rejections inflate
    off = run(scattered[:3], modest[:3], ConsistencyOptions(jump_erratic_probability=None))
    assert off.should_recover(3 * S, position_std_m=0.5).kind == "inflate"  # type: ignore[union-attr]


def test_gps_whose_velocity_agrees_gets_one_more_fix_before_the_filter_is_lost() -> None:
    """A drifting filter is off in velocity too; multipath moves GPS position only. While the
    velocity part of every rejected fix is inside its own gate, three rejections are too few
    (one degree of freedom per axis about the quadratic): a fourth decides, by scatter or by
    trend. A velocity that disagrees decides at the third as before."""
    rng = np.random.default_rng(5)
    S_cov = np.eye(6)
    gate = 22.5  # chi-square(6) at 0.999

    def run(position: list[np.ndarray], velocity: list[np.ndarray]) -> ConsistencyMonitor:
        m = ConsistencyMonitor(ConsistencyOptions())
        m.observe("gps", True, 2.0, 6, 0, gate, np.zeros(6), np.zeros(6), S_cov)
        for k, (p, v) in enumerate(zip(position, velocity, strict=True), start=1):
            r = np.r_[p, v]
            m.observe("gps", False, float(r @ r), 6, k * S, gate, r, r, S_cov)
        return m

    scattered = [rng.normal(0.0, 8.0, 3) for _ in range(4)]
    trend = [np.array([6.0, 0.0, 0.0]) * k for k in range(1, 5)]
    calm = [rng.normal(0.0, 1.0, 3) for _ in range(4)]  # inside chi-square(3) at 0.999
    off = [np.array([0.0, 6.0, 0.0]) * k for k in range(1, 5)]
    assert run(scattered[:3], calm[:3]).should_recover(3 * S, position_std_m=0.5) is None
    action = run(scattered, calm).should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust" and "scatter" in action.reason
    # a filter whose position error grows at the rate its (agreeing) velocity error shows
    drifting = [np.array([3.0, 0.0, 0.0]) * k for k in range(1, 5)]
    following = [np.array([3.0, 0.0, 0.0]) + 0.3 * c for c in calm]
    action = run(drifting, following).should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "inflate"
    action = run(trend[:3], off[:3]).should_recover(3 * S, position_std_m=0.5)
    assert action is not None and action.kind == "inflate"
    # no patience: the third rejection decides whatever the velocity says
    m = ConsistencyMonitor(ConsistencyOptions(rate_channels=()))
    m.observe("gps", True, 2.0, 6, 0, gate, np.zeros(6), np.zeros(6), S_cov)
    for k, p in enumerate(scattered[:3], start=1):
        r = np.r_[p, calm[k - 1]]
        m.observe("gps", False, float(r @ r), 6, k * S, gate, r, r, S_cov)
    assert m.should_recover(3 * S, position_std_m=0.5) is not None


def test_gps_whose_velocity_alone_jumps_is_fused_without_it() -> None:
    """GPS velocity far off from one fix on while its position agrees: after three
    rejected fixes the monitor answers ``drop_rate`` (counted, its evidence used up); with
    ``rate_drop`` off it is a jump to distrust. A velocity disagreement that grows from small
    (a drifting filter, a bias step) is no jump: no ``drop_rate``."""
    S_cov = np.eye(6)
    gate = 22.5

    def run(velocity: list[np.ndarray], options: ConsistencyOptions | None = None,
            position: float = 0.5) -> ConsistencyMonitor:  # fmt: skip
        m = ConsistencyMonitor(options or ConsistencyOptions())
        m.observe("gps", True, 2.0, 6, 0, gate, np.zeros(6), np.zeros(6), S_cov)
        for k, v in enumerate(velocity, start=1):
            r = np.r_[np.full(3, position), v]
            m.observe("gps", False, float(r @ r), 6, k * S, gate, r, r, S_cov)
        return m

    jumped = [np.array([50.0, 0.0, 0.0])] * 3
    m = run(jumped)
    action = m.should_recover(3 * S, position_std_m=0.5)
    assert action is not None and action.kind == "drop_rate" and action.sensors == ("gps",)
    assert "velocity alone" in action.reason and m.summary()["rate_drops"] == 1
    assert m.should_recover(3 * S, position_std_m=0.5) is None  # the evidence is used up
    action = run(jumped, ConsistencyOptions(rate_drop=False)).should_recover(
        3 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust"
    # the position disagreeing too: no drop (a jump of the whole fix)
    action = run(jumped, position=20.0).should_recover(3 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust"
    growing = [np.array([4.0, 0.0, 0.0]) * k for k in range(1, 4)]  # NIS 16 → 144: no jump
    action = run(growing).should_recover(3 * S, position_std_m=0.5)
    assert action is None or action.kind != "drop_rate"


def test_gps_position_running_off_against_its_own_velocity_is_distrusted() -> None:
    """A filter error obeys kinematics: its position innovation grows at the rate its
    velocity innovation shows. GPS positions that run off at 6 per second while GPS velocity
    agrees (a wandering float solution) are the receiver's: distrusted, with the speed in the
    reason, not taken for a lost filter; with the multipath test off, inflated as before."""
    rng = np.random.default_rng(11)
    S_cov = np.eye(6)

    def run(options: ConsistencyOptions | None = None) -> ConsistencyMonitor:
        m = ConsistencyMonitor(options or ConsistencyOptions())
        m.observe("gps", True, 2.0, 6, 0, 22.5, np.zeros(6), np.zeros(6), S_cov)
        for k in range(1, 5):
            r = np.r_[np.array([6.0, 0.0, 0.0]) * k + rng.normal(0.0, 0.3, 3),
                      rng.normal(0.0, 1.0, 3)]  # fmt: skip
            m.observe("gps", False, float(r @ r), 6, k * S, 22.5, r, r, S_cov)
        return m

    action = run().should_recover(4 * S, position_std_m=0.5)
    assert action is not None and action.kind == "distrust", action
    assert "running off at 6" in action.reason and "against its own velocity" in action.reason
    off = run(ConsistencyOptions(jump_erratic_probability=None))
    assert off.should_recover(4 * S, position_std_m=0.5).kind == "inflate"  # type: ignore[union-attr]


def test_a_magnetometer_whose_accepted_innovations_lean_is_held() -> None:
    """Each sample inside its gate, five in a row leaning one way (a field turned by steel
    nearby): ``hold`` for the magnetometer, counted, its window used up; white innovations
    give none, nor does the test switched off."""
    rng = np.random.default_rng(2)

    def feed(m: ConsistencyMonitor, offset: np.ndarray) -> None:
        for k in range(5):
            w = offset + rng.normal(0.0, 1.0, 3)
            m.observe("mag", True, float(w @ w), 3, k * S // 10, 16.3, w)

    m = ConsistencyMonitor()
    feed(m, np.zeros(3))
    assert m.leaning(S) is None
    feed(m, np.array([3.0, 0.0, 0.0]))  # NIS about 10 each, under the gate of 16.3
    action = m.leaning(S)
    assert action is not None and action.kind == "hold" and action.sensors == ("mag",)
    assert "mag innovations share an offset" in action.reason and m.summary()["holds"] == 1
    assert m.leaning(S) is None  # used up
    off = ConsistencyMonitor(ConsistencyOptions(lean_probability=None))
    feed(off, np.array([3.0, 0.0, 0.0]))
    assert off.leaning(S) is None


def test_a_fast_gps_fills_its_bias_window_at_the_test_spacing_only() -> None:
    """A 50 Hz GPS: 3 fixes 40 ms apart are no window (a test at every fix raised 25 false
    alarms in 20 s); those at least ``BIAS_WINDOW_MIN_SPACING_S`` apart are."""
    from svains.navigation.consistency import BIAS_WINDOW_MIN_SPACING_S

    assert BIAS_WINDOW_MIN_SPACING_S == 0.5
    lean = [2.5, 0.0, 0.0]  # 3 * 6.25 = 18.75 > 11.34: an alarm over any 3 of them
    m = ConsistencyMonitor(ON)
    t = _observe_at(m, [1.00, 1.02, 1.04, 1.06, 1.48], lean)
    assert m.biased(t) is None  # kept: 1.00 only
    t = _observe_at(m, [1.50, 1.52, 1.98], lean)
    assert m.biased(t) is None  # kept: 1.00, 1.50
    t = _observe_at(m, [2.00], lean)
    action = m.biased(t)
    assert action is not None and action.window_s == 1.0
