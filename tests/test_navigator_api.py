"""The Navigator's contract on small synthetic streams: static start, duplicate IMU stamps,
bad configurations, copies of fed images, outputs."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains import Navigator, NavState, RunConfig
from svains.errors import ClosedError, ConfigError, InitialisationError
from svains.navigation.event_queue import FRAME
from svains.navigation.options import InitOptions
from svains.navigation.outputs import RunResult
from svains.sensors.types import CameraCalib, GpsCalib, Rig

G = 9.81


def _feed_static(nav: Navigator, seconds: float, rng: np.random.Generator,
                 accel: np.ndarray | None = None) -> None:
    for k in range(int(seconds * 200)):
        a = np.array([0.0, 0.0, G]) if accel is None else accel
        nav.feed_imu(1_000_000_000 + k * 5_000_000, 1e-3 * rng.standard_normal(3),
                     a + 1e-2 * rng.standard_normal(3))


def test_static_start_outputs_and_state() -> None:
    seen: list[NavState] = []
    nav = Navigator(RunConfig(), Rig(), on_output=seen.append)
    assert nav.state() is None and nav.status == "initialising"
    _feed_static(nav, 3.0, np.random.default_rng(0))
    assert nav.status == "running" and nav.t0_ns == 1_010_000_000  # the third IMU sample
    s = nav.state()
    assert s is not None and s.bg_B is not None and s.P.shape == (18, 18)
    np.testing.assert_allclose(s.T_W_B[:3, :3] @ [0, 0, 1], [0, 0, 1], atol=1e-2)
    res = nav.close()
    assert [o.t_ns for o in seen] == res.t_ns.tolist() == [o.t_ns for o in nav.outputs()]
    assert np.linalg.norm(res.x[-1, 3:6]) < 0.05  # at rest
    assert nav.status == "closed" and nav.close() is res


def test_undrained_outputs_keep_the_latest_and_a_replay_keeps_none(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A user's probe: the states for ``outputs()`` were kept without end (134 MB per hour),
    also by the replay, which takes them by ``on_output`` and never drains them."""
    from svains.navigation import navigator

    monkeypatch.setattr(navigator, "OUTPUTS_KEPT", 5)
    with caplog.at_level("WARNING", logger="svains.navigation.navigator"):
        nav = Navigator(RunConfig(), Rig())
        _feed_static(nav, 4.0, np.random.default_rng(0))
        res = nav.close()
    assert res.t_ns.size > 10
    assert [o.t_ns for o in nav.outputs()] == res.t_ns[-5:].tolist()
    assert caplog.text.count("outputs() not drained for 5 states") == 1
    seen: list[NavState] = []
    nav = Navigator(RunConfig(), Rig(), on_output=seen.append, keep_outputs=False)
    _feed_static(nav, 4.0, np.random.default_rng(0))
    res = nav.close()
    assert [o.t_ns for o in seen] == res.t_ns.tolist() and list(nav.outputs()) == []


def test_a_restarted_process_goes_on_from_the_last_state() -> None:
    """A live user's probe: a new Navigator started from the old one's ``state()`` raised "the
    initial time must be an IMU sample time" at its first sample (the samples fed were the
    ones after it) and no helper built the start from a NavState. Now
    ``InitialState.from_nav_state`` and a start at the next sample, up to 50 ms later."""
    from svains import InitialState

    rng = np.random.default_rng(1)
    cfg = RunConfig()
    old = Navigator(cfg, Rig())
    _feed_static(old, 4.0, rng)
    s = old.state()
    assert s is not None
    start = InitialState.from_nav_state(s)
    assert start.x.shape == (19,) and start.P.shape == (18, 18) and start.t_ns == s.t_ns
    new = Navigator(replace(cfg, init=InitOptions(mode="groundtruth")), Rig(),
                    initial_state=start)
    for k in range(1, 400):  # the samples after the saved state's, 2.5 ms off its grid
        new.feed_imu(s.t_ns + 2_500_000 + k * 5_000_000, 1e-3 * rng.standard_normal(3),
                     np.array([0.0, 0.0, G]) + 1e-2 * rng.standard_normal(3))
    assert new.status == "running" and new.t0_ns == s.t_ns + 7_500_000
    res = new.close()
    np.testing.assert_allclose(res.x[0, :3], s.p_W_B + s.v_W_B * 0.0075, atol=1e-9)
    # the old run's rest noise is handed on by the caller (a user's probe: the restart fell
    # back to the calibration's densities, in silence)
    assert old.rest_noise is not None and old.rest_noise.dof > 0
    assert new.rest_noise is None
    again = Navigator(replace(cfg, init=InitOptions(mode="groundtruth")), Rig(),
                      initial_state=start, rest_noise=old.rest_noise)
    for k in range(1, 40):
        again.feed_imu(s.t_ns + 2_500_000 + k * 5_000_000, np.zeros(3), np.array([0.0, 0.0, G]))
    assert again.rest_noise is old.rest_noise
    late = Navigator(replace(cfg, init=InitOptions(mode="groundtruth")), Rig(),
                     initial_state=start)
    with pytest.raises(InitialisationError, match=r"first sample after it comes 1\.000 s later"):
        for k in range(40):
            late.feed_imu(s.t_ns + 1_000_000_000 + k * 5_000_000, np.zeros(3),
                          np.array([0.0, 0.0, G]))


def test_duplicate_and_backward_imu_stamps_are_dropped_and_counted() -> None:
    nav = Navigator(RunConfig(), Rig())
    _feed_static(nav, 2.5, np.random.default_rng(1))
    n = nav.history.n
    nav.feed_imu(1_000_000_000, np.zeros(3), np.array([0, 0, G]))
    nav.feed_imu(nav.history.last_ns, np.zeros(3), np.array([0, 0, G]))
    assert nav.history.n == n
    assert nav.close().report["dropped"] == {"imu": 2}


def test_a_moving_start_is_refused_with_the_reason() -> None:
    nav = Navigator(RunConfig(), Rig())
    rng = np.random.default_rng(2)
    with pytest.raises(InitialisationError, match="IMU is not static"):
        for k in range(600):
            a = np.array([0.0, 0.0, G]) + np.array([2.0 * np.sin(k / 20), 0.0, 0.0])
            nav.feed_imu(k * 5_000_000, 1e-3 * rng.standard_normal(3), a)


def test_bad_configurations_name_the_problem() -> None:
    with pytest.raises(ConfigError, match="method vo has no filter"):
        Navigator(RunConfig(method="vo"), Rig())
    with pytest.raises(ConfigError, match="needs the initial state"):
        Navigator(RunConfig(init=InitOptions(mode="groundtruth")), Rig())
    with pytest.raises(ConfigError, match=r"needs a GPS: the rig has none .* --init static"):
        Navigator(RunConfig(init=InitOptions(mode="gps")), Rig())
    with pytest.raises(ConfigError, match="no IMU sample was fed"):
        Navigator(RunConfig(), Rig()).close()
    # a vision method on a rig without cameras: its frames were dropped one by one and the
    # run went on inertial only (a probe)
    for method in ("lc", "tc", "3d"):
        with pytest.raises(ConfigError, match=rf"method {method} needs the cam0 and cam1 "
                                              r"calibrations .* use method ins"):
            Navigator(RunConfig(method=method), Rig(cam1=_stereo_rig().cam1))


def test_fed_images_are_copied() -> None:
    nav = Navigator(RunConfig(method="3d"), _stereo_rig())
    left, right = np.full((4, 6), 7, np.uint8), np.full((4, 6), 8, np.uint8)
    nav.feed_stereo(5, left, right)
    left[:] = right[:] = 0  # the driver reuses its buffers
    (_, kind, _, payload), = nav.queue._heap
    assert kind == FRAME and payload[1].max() == 7 and payload[2].max() == 8


@pytest.mark.parametrize(("dtype", "hint"), [(np.uint16, "for 16-bit"), (np.float32, "floats")])
def test_a_pair_that_is_not_8_bit_is_refused_naming_a_conversion(dtype: type,
                                                                 hint: str) -> None:  # fmt: skip
    # a cast would wrap 16-bit grey levels modulo 256 and floats in 0-1 to black
    nav = Navigator(RunConfig(method="3d"), _stereo_rig())
    img = np.zeros((4, 6), dtype)
    want = rf"the right image is {np.dtype(dtype)}, not uint8.*{hint}"
    with pytest.raises(TypeError, match=want):
        nav.feed_stereo(5, np.zeros((4, 6), np.uint8), img)
    assert not nav.queue._heap


def test_a_non_finite_sample_is_dropped_even_without_an_imu_calibration() -> None:
    # Rig() has no IMU calibration: the guard runs with the filter's default densities
    nav = Navigator(RunConfig(), Rig())
    rng = np.random.default_rng(3)
    _feed_static(nav, 3.0, rng)
    t = 1_000_000_000 + 600 * 5_000_000
    nav.feed_imu(t, [np.nan, 0.0, 0.0], [0.0, 0.0, G])
    for k in range(1, 200):
        nav.feed_imu(t + k * 5_000_000, 1e-3 * rng.standard_normal(3), [0.0, 0.0, G])
    res = nav.close()  # before: "process model returned non-finite sigma points"
    assert res.report["imu_faults"]["dropped"]["nonfinite"] == 1
    assert np.all(np.isfinite(res.x)) and np.linalg.norm(res.x[-1, 3:6]) < 0.05


def test_inputs_of_the_wrong_shape_are_refused_naming_the_argument() -> None:
    rig = replace(_stereo_rig(), gps=GpsCalib(np.zeros(3), 1.0, 1.0, 0.1))
    nav = Navigator(RunConfig(method="3d"), rig)
    with pytest.raises(ValueError, match=r"feed_imu: gyro_S must hold 3 values, got shape \(2,\)"):
        nav.feed_imu(1, [0.0, 0.0], [0.0, 0.0, G])
    with pytest.raises(ValueError, match=r"feed_gps: p_W_G must hold 3 values, got shape \(2,\)"):
        nav.feed_gps(1, [49.0, 8.3], None)
    with pytest.raises(ValueError, match=r"feed_gps: v_W_G must hold 3 values"):
        nav.feed_gps(1, [0.0, 0.0, 0.0], [1.0])
    with pytest.raises(ValueError, match=r"feed_mag: m_S must hold 3 values, got shape \(4,\)"):
        nav.feed_mag(1, np.zeros(4))
    with pytest.raises(ValueError, match=r"feed_tracks: track_id \(M,\), uv_left and uv_right "
                       r"\(M, 2\) expected, got \(2,\), \(1, 2\), \(2, 2\)"):  # fmt: skip
        nav.feed_tracks(1, [1, 2], [[0.0, 0.0]], [[0.0, 0.0], [1.0, 1.0]])
    assert not nav.queue._heap and nav.history.n == 0


def test_stamps_that_are_not_whole_nanoseconds_are_refused_naming_the_call() -> None:
    """Seconds as floats were truncated to a few nanoseconds and dropped as repeats, one
    warning each (a user's probe); whole numbers of any numeric type are stamps."""
    rig = replace(_stereo_rig(), gps=GpsCalib(np.zeros(3), 1.0, 1.0, 0.1))
    nav = Navigator(RunConfig(method="3d"), rig)
    hint = r"got 12\.345 \(a time in seconds\? pass round\(t_s \* 1e9\)\)"
    with pytest.raises(ValueError, match=r"feed_imu: t_ns must be integer nanoseconds, " + hint):
        nav.feed_imu(12.345, [0.0, 0.0, 0.0], [0.0, 0.0, G])
    with pytest.raises(ValueError, match=r"feed_gps: t_ns must be integer nanoseconds, " + hint):
        nav.feed_gps(np.float64(12.345), [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"feed_sonar: t_ns must be integer nanoseconds, got nan"):
        nav.feed_sonar(float("nan"), 2.0)
    with pytest.raises(ValueError, match=r"feed_mag: t_ns must be integer nanoseconds, got True"):
        nav.feed_mag(True, [0.2, 0.0, -0.4])
    with pytest.raises(ValueError, match=r"feed_tracks: t_ns must be integer nanoseconds, got '1'"):
        nav.feed_tracks("1", [1], [[0.0, 0.0]], [[0.0, 0.0]])
    with pytest.raises(ValueError, match=r"feed_stereo: t_ns must be integer nanoseconds"):
        nav.feed_stereo(0.5, np.zeros((4, 4), np.uint8), np.ones((4, 4), np.uint8))
    assert not nav.queue._heap and nav.history.n == 0
    # Whole numbers pass whatever their type: a pandas column of float nanoseconds, numpy ints.
    rng = np.random.default_rng(5)
    stamps = (1_000_000_000, np.int64(1_005_000_000), 1.01e9, np.float32(1.015e9), 1_020_000_000)
    for t in stamps:
        nav.feed_imu(t, rng.normal(0.0, 1e-3, 3), rng.normal([0.0, 0.0, G], 1e-2))
    assert nav.queue.dropped == {}
    assert nav.history.t_ns.tolist()[:4] == [1_000_000_000, 1_005_000_000, 1_010_000_000,
                                             1_015_000_000]


@pytest.mark.parametrize(("scale", "warned"), [(1.0, False), (1 / G, True)])
def test_a_start_from_a_given_state_warns_of_an_accelerometer_in_g(
    scale: float, warned: bool, caplog: pytest.LogCaptureFixture
) -> None:
    from svains.models.state import BIASED
    from svains.navigation.init import InitialState

    x = np.zeros(BIASED.nx)
    x[6] = 1.0  # identity attitude, w first
    init = InitialState(1_000_000_000, x, np.eye(BIASED.ndx) * 1e-4)
    nav = Navigator(RunConfig(init=InitOptions(mode="groundtruth")), Rig(), initial_state=init)
    with caplog.at_level("WARNING", logger="svains.navigation.navigator"):
        _feed_static(nav, 3.0, np.random.default_rng(4), accel=np.array([0.0, 0.0, G * scale]))
    text = "over the first 2 s of IMU samples the accelerometer's median magnitude is 1"
    assert (text in caplog.text) is warned
    assert caplog.text.count("accelerometer's median magnitude") == int(warned)  # once


def _gps_rig() -> Rig:
    return Rig(gps=GpsCalib(np.zeros(3), 1.0, 0.5, 0.1))


def _stereo_rig() -> Rig:
    """A 20 Hz stereo pair 0.1 m wide, 640x480, no distortion."""
    T1 = np.eye(4)
    T1[0, 3] = 0.1
    cams = [CameraCalib(name, T, 20.0, (640, 480), np.array([400.0, 400.0, 320.0, 240.0]),
                        "radtan", np.zeros(4)) for name, T in (("cam0", np.eye(4)), ("cam1", T1))]
    return Rig(cam0=cams[0], cam1=cams[1])


def _feed_resting_with_fixes(nav: Navigator, seconds: float, rng: np.random.Generator,
                             feed_fix: Callable[[int, int], None]) -> None:  # fmt: skip
    """A resting IMU at 200 Hz from 1 s, ``feed_fix(t_ns, second)`` half a second into every
    second (the caller feeds the GPS)."""
    for k in range(int(seconds * 200)):
        t = 1_000_000_000 + k * 5_000_000
        nav.feed_imu(t, 1e-3 * rng.standard_normal(3),
                     [0.0, 0.0, G] + 1e-2 * rng.standard_normal(3))  # fmt: skip
        if k % 200 == 100:
            feed_fix(t, k // 200)


def test_a_non_finite_gps_fix_is_dropped_and_counted() -> None:
    """A NaN in a fed GPS position or velocity (a user's probe): before, a FilterError raised by
    a later feed_imu ("gps: non-finite innovation"), or a NaN heading and a non-finite
    covariance; now dropped and counted as the magnetometer's and sonar's are."""
    nav = Navigator(RunConfig(), _gps_rig())
    rng = np.random.default_rng(5)

    def fix(t: int, second: int) -> None:
        p, v = 0.3 * rng.standard_normal(3), 0.05 * rng.standard_normal(3)
        if second == 3:
            p[0] = np.nan
        if second == 5:
            v[2] = np.inf
        nav.feed_gps(t, p, v)

    _feed_resting_with_fixes(nav, 8.0, rng, fix)
    res = nav.close()
    assert res.report["dropped"] == {"gps": 2}
    assert res.report["measurements"]["gps"]["fused"] >= 4
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P9))


def test_feeding_after_close_is_refused_and_an_early_close_leaves_the_run_whole() -> None:
    nav = Navigator(RunConfig(), Rig())
    _feed_static(nav, 3.0, np.random.default_rng(6))
    with pytest.raises(ValueError, match=r"close: until_ns 5 is before \d+ ns, up to which the "
                       r"estimator has already processed its measurements"):  # fmt: skip
        nav.close(until_ns=5)
    res = nav.close()  # before: every later close() raised "cannot propagate backwards"
    assert res.t_ns[-1] == nav.history.last_ns
    with pytest.raises(ClosedError, match=r"feed_imu after close\(\): this Navigator's run is "
                       r"over; make a new Navigator for another"):  # fmt: skip
        nav.feed_imu(res.t_ns[-1] + 5_000_000, np.zeros(3), [0.0, 0.0, G])
    with pytest.raises(ClosedError, match=r"feed_gps after close\(\)"):
        nav.feed_gps(res.t_ns[-1], np.zeros(3))
    assert nav.close() is res


def test_misused_arguments_get_a_typed_error_naming_them() -> None:
    with pytest.raises(TypeError, match=r"Navigator: config must be a RunConfig, got dict"):
        Navigator({"method": "3d"}, Rig())  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="Navigator: rig must be a Rig, got NoneType"):
        Navigator(RunConfig(), None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="Navigator: on_output must be callable, got 42"):
        Navigator(RunConfig(), Rig(), on_output=42)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"rig\.gravity_W has magnitude 1 m/s², expected "
                       r"9\.7-9\.9 \(Earth\)"):  # fmt: skip
        Navigator(RunConfig(), Rig(gravity_W=(0.0, 0.0, -1.0)))
    with pytest.raises(ConfigError, match=r"output_period_s must be a number, got '0\.1'"):
        RunConfig(output_period_s="0.1")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"an initial_state is given but init\.mode is 'gps'"):
        Navigator(RunConfig(init=InitOptions(mode="gps")), _gps_rig(),
                  initial_state=object())  # type: ignore[arg-type]
    stereo = _stereo_rig()
    nav = Navigator(RunConfig(method="3d"), replace(_gps_rig(), cam0=stereo.cam0, cam1=stereo.cam1))
    with pytest.raises(ValueError, match=r"feed_imu: gyro_S must hold 3 numbers, got \['a'"):
        nav.feed_imu(1, ["a", "b", "c"], [0.0, 0.0, G])
    with pytest.raises(ValueError, match=r"feed_sonar: range_m must be one number, got shape "
                       r"\(2,\)"):  # fmt: skip
        nav.feed_sonar(1, np.array([1.0, 2.0]))
    with pytest.raises(TypeError, match="feed_stereo: the left image must be a numpy array, "
                       "got NoneType"):  # fmt: skip
        nav.feed_stereo(1, None, None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"the right image must be \(H, W\) grey or \(H, W, "
                       r"3\|4\) colour, got shape \(6,\)"):  # fmt: skip
        nav.feed_stereo(1, np.zeros((4, 6), np.uint8), np.zeros(6, np.uint8))
    with pytest.raises(ValueError, match=r"feed_tracks: track_id must hold integers, got "
                       r"float64 \[1\.7\]"):  # fmt: skip
        nav.feed_tracks(1, [1.7], [[1.0, 2.0]], [[0.5, 2.0]])
    assert not nav.queue._heap and nav.history.n == 0
    # a driver's single-channel frames (H, W, 1) are grey images
    nav.feed_stereo(5, np.full((4, 6, 1), 7, np.uint8), np.full((4, 6, 1), 8, np.uint8))
    nav.feed_tracks(6, [1.0, 2.0], [[1.0, 2.0], [3.0, 4.0]], [[0.5, 2.0], [2.5, 4.0]])
    (_, _, _, first), (_, _, _, second) = sorted(nav.queue._heap)
    assert first[1].shape == first[2].shape == (4, 6) and second[1].dtype == np.int64


def test_a_gps_start_whose_fixes_all_came_late_says_so() -> None:
    """Fixes fed 150 ms after their time with the default 0.1 s window: all dropped as late,
    and the start's error said only that the stream had no fix (a user's probe)."""
    nav = Navigator(RunConfig(init=InitOptions(mode="gps")), _gps_rig())
    rng = np.random.default_rng(7)
    pending: list[int] = []
    for k in range(int(6.0 * 200)):
        t = 1_000_000_000 + k * 5_000_000
        nav.feed_imu(t, 1e-3 * rng.standard_normal(3), [0.0, 0.0, G])
        if k % 200 == 0:
            pending.append(t)
        if pending and t - pending[0] >= 150_000_000:
            nav.feed_gps(pending.pop(0), np.zeros(3), np.zeros(3))
    with pytest.raises(InitialisationError, match=r"; dropped for coming more than buffer\."
                       r"window_s \(0\.1 s\) after the IMU sample of their time: 6 gps "
                       r"measurement\(s\) \(a longer window waits for them\)"):  # fmt: skip
        nav.close()
    assert nav.queue.late == {"gps": 6}


@pytest.mark.parametrize(("settings", "warned"), [
    ({"use_gps": False}, True),
    ({"gps_outages": ((0.0, 15.0),)}, True),
    ({"gps_until_s": 0.0}, True),
    ({"gps_outages": ((5.0, 10.0),)}, False),
    ({}, False),
])  # fmt: skip
def test_a_gps_start_without_gps_fused_there_is_warned(
    settings: dict, warned: bool, caplog: pytest.LogCaptureFixture
) -> None:
    """``--init gps --no-gps`` started from the fixes without a word (a user's probe)."""
    with caplog.at_level("WARNING", logger="svains.navigation.navigator"):
        Navigator(RunConfig(init=InitOptions(mode="gps"), **settings), _gps_rig())
    assert ("init.mode gps takes the start from the GPS fixes, though the run fuses none "
            "there" in caplog.text) is warned  # fmt: skip


def test_the_reported_output_rate_is_the_one_written() -> None:
    """An output period below the IMU's spacing writes at the IMU's rate; the report said
    1000 Hz for 1 ms on a 100 Hz stream (a user's probe)."""
    nav = Navigator(RunConfig(output_period_s=0.001), Rig())
    rng = np.random.default_rng(8)
    for k in range(int(4.0 * 100)):  # a 100 Hz IMU
        nav.feed_imu(1_000_000_000 + k * 10_000_000, 1e-3 * rng.standard_normal(3),
                     [0.0, 0.0, G] + 1e-2 * rng.standard_normal(3))  # fmt: skip
    res = nav.close()
    assert res.report["states_rate_hz"] == pytest.approx(100.0, rel=0.01)
    assert np.median(np.diff(res.t_ns)) == 10_000_000


def test_a_frame_fed_twice_is_dropped_and_the_run_unchanged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Every frame fed twice through feed_tracks (a driver repeating its message): 0 of 107
    frames fused, ATE 1262 m, not a word (a user's probe). The second is dropped, counted."""
    from dataclasses import replace as dc_replace

    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.options import InitOptions, RunOptions
    from svains.sim import SimConfig, simulate

    cfg = SimConfig()
    cfg = dc_replace(cfg, duration_s=6.0, seed=4, gps=dc_replace(cfg.gps, enabled=False),
                     camera=dc_replace(cfg.camera, rate_hz=5.0, render_images=False))  # fmt: skip
    ds = load_dataset(simulate(cfg, tmp_path / "ds"))
    opts = RunOptions(init=InitOptions(mode="groundtruth"))
    clean = run_method(ds, "3d", opts).report
    once = Navigator.feed_tracks

    def twice(self: Navigator, *args: object) -> None:
        once(self, *args)  # type: ignore[arg-type]
        once(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(Navigator, "feed_tracks", twice)
    with caplog.at_level("WARNING"):
        doubled = run_method(ds, "3d", opts).report
    assert "a second frame with the same stamp; the first is kept" in caplog.text
    assert doubled["dropped"]["frame"] >= 28  # 6 s at 5 Hz: each frame's second copy
    assert doubled["ate_rmse_m"] == clean["ate_rmse_m"]


def test_non_finite_pixels_and_identical_stereo_images_are_dropped(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """NaN pixels were fused as numbers; a right image equal to the left (one camera sent
    twice) put every point at infinity; both silently (a user's probe)."""
    nav = Navigator(RunConfig(method="3d"), replace(_stereo_rig(), imu_period_s=0.005))
    with caplog.at_level("WARNING"):
        nav.feed_tracks(1_000, [1, 2, 3], [[1.0, 2.0], [np.nan, 4.0], [5.0, 6.0]],
                        [[0.5, 2.0], [2.5, 4.0], [4.5, np.inf]])  # fmt: skip
        img = np.zeros((4, 6), np.uint8)
        nav.feed_stereo(2_000, img, img.copy())
        img = np.arange(24, dtype=np.uint8).reshape(4, 6)
        nav.feed_stereo(3_000, img, img.copy())
    assert nav.queue.dropped == {"feature": 1, "frame": 2}
    assert "2 of 3 features with non-finite pixels" in caplog.text
    # a blank pair (a covered camera) said so, not taken for one image sent twice
    assert ("the left and right images are identical: both blank, every pixel 0 (a camera "
            "covered, off or not yet exposed?)") in caplog.text
    assert "the left and right images are identical (one camera's image sent twice?)" \
        in caplog.text
    queued = [e for e in nav.queue._heap if e[0] == 1_000]  # the frame, waiting for the IMU
    assert len(queued) == 1 and queued[0][3][1].tolist() == [1]  # the finite feature only


def test_measurements_on_another_clock_are_named_at_close(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Frames stamped an hour ahead were never used: a pure INS run, one "no vision fused"
    line (a user's probe). close() names what was left and how far after the last IMU sample."""
    nav = Navigator(RunConfig(method="3d"), replace(_stereo_rig(), imu_period_s=0.005))
    rng = np.random.default_rng(3)
    hour = 3_600_000_000_000
    for k in range(5):
        nav.feed_tracks(1_000_000_000 + k * 200_000_000 + hour, [1], [[1.0, 2.0]], [[0.5, 2.0]])
    _feed_static(nav, 3.0, rng)
    with caplog.at_level("WARNING"):
        nav.close()
    assert re.search(r"5 frame stamped up to 3597\.\d s after the last IMU sample were never "
                     r"used: on another clock", caplog.text)  # fmt: skip


def test_slow_imu_stamps_in_microseconds_are_named_against_the_rigs_rate() -> None:
    """A 100 Hz IMU kept at 40 ms (KITTI raw's OXTS) stamped in µs steps by 40000, inside the
    50 kHz any spacing allows: the rig's rate_hz tells it (a user's probe)."""
    from svains.sensors.types import ImuCalib

    rig = Rig(imu=ImuCalib(np.eye(4), 100.0, 1.7e-4, 2e-5, 2e-3, 3e-3))
    nav = Navigator(RunConfig(), rig)
    rng = np.random.default_rng(2)
    with pytest.raises(ConfigError, match=r"feed_imu: samples come at 2\.5e\+04 Hz if the stamps "
                       r"are nanoseconds \(250x the rig's IMU rate_hz 100\): they look like "
                       r"microseconds \(25 Hz then\)"):  # fmt: skip
        for k in range(40):
            nav.feed_imu(10**9 + k * 40_000, 1e-3 * rng.standard_normal(3),
                         [0.0, 0.0, G] + 1e-2 * rng.standard_normal(3))


@pytest.mark.parametrize(("step", "unit"), [(5_000, "microseconds"), (5, "milliseconds")])
def test_imu_stamps_in_another_unit_are_named(step: int, unit: str) -> None:
    """Stamps in µs or ms fed online were blamed on a short static start (a user's probe)."""
    nav = Navigator(RunConfig(), Rig(imu_period_s=0.005))
    rng = np.random.default_rng(1)
    with pytest.raises(ConfigError, match=rf"feed_imu: timestamps advance by a median {step} "
                       rf"per sample, .* they look like {unit} \(feed_\* take integer "
                       r"nanoseconds\)"):  # fmt: skip
        for k in range(40):
            nav.feed_imu(10**9 + k * step, 1e-3 * rng.standard_normal(3),
                         [0.0, 0.0, G] + 1e-2 * rng.standard_normal(3))


def test_the_vision_gap_says_frames_were_dropped_before_the_filter(
    kitti_raw: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Blank frames dropped by the queue never reach the filter: the gap's warning said "no
    frame since" (a reviewer's case); it now counts them."""
    from dataclasses import replace

    from svains.datasets import load_dataset
    from svains.replay.replay import (
        feed,
        groundtruth_start,
        measurements,
        resolve_config,
        rig_from_dataset,
    )

    ds = load_dataset(kitti_raw)
    config = resolve_config(ds, RunConfig(method="3d", use_gps=False, use_mag=False,
                                          duration_s=12.0,
                                          init=InitOptions(mode="groundtruth")))  # fmt: skip
    config = replace(config, vision=replace(config.vision, source="images"))
    init = groundtruth_start(ds, config, None)
    nav = Navigator(config, rig_from_dataset(ds), initial_state=init)
    with caplog.at_level("WARNING"):
        for t, kind, payload in measurements(ds, config, init.t_ns):
            if kind == FRAME and init.t_ns + 8e9 < t < init.t_ns + 11e9:
                payload = (payload[0], np.zeros_like(payload[1]), np.zeros_like(payload[2]))
            feed(nav, kind, t, payload)
        nav.close()
    assert re.search(r"no vision fused for [\d.]+ s: the estimate is inertial only \((\d+) frames "
                     r"since; \1 dropped before the filter", caplog.text), caplog.text


def test_a_driver_reusing_its_gps_buffers_does_not_change_the_fixes_held() -> None:
    """A user's probe: fixes were kept by reference, so a driver that rewrites one buffer per
    fix left every held fix reading the newest (the ``gps`` start then refused five pairs as
    "0.0 m apart"). Each fix is copied: the run equals one fed fresh arrays."""
    def run(reuse: bool) -> RunResult:
        nav = Navigator(RunConfig(init=InitOptions(mode="gps")), _gps_rig())
        rng = np.random.default_rng(7)
        buf_p, buf_v = np.zeros(3), np.zeros(3)

        def fix(t: int, _: int) -> None:
            p, v = 0.3 * rng.standard_normal(3), 0.05 * rng.standard_normal(3)
            if reuse:
                buf_p[:], buf_v[:] = p, v
                p, v = buf_p, buf_v
            nav.feed_gps(t, p, v)

        _feed_resting_with_fixes(nav, 6.0, rng, fix)
        return nav.close()

    results = [run(False), run(True)]
    np.testing.assert_array_equal(results[0].x, results[1].x)


def test_frames_fed_to_an_ins_after_close_are_refused() -> None:
    nav = Navigator(RunConfig(method="ins"), Rig())
    _feed_static(nav, 3.0, np.random.default_rng(8))
    nav.close()
    for call in (lambda: nav.feed_stereo(0, np.zeros((2, 2), np.uint8), np.zeros((2, 2), np.uint8)),
                 lambda: nav.feed_tracks(0, [1], [[0.0, 0.0]], [[0.0, 0.0]])):  # fmt: skip
        with pytest.raises(ClosedError, match=r"feed_(stereo|tracks) after close\(\)"):
            call()


def test_a_given_start_with_a_quaternion_that_is_not_unit_is_refused() -> None:
    from svains import InitialState

    x = np.zeros(19)
    x[6:10] = [3.0, 0.0, 0.0, 0.0]
    cfg = replace(RunConfig(), init=InitOptions(mode="groundtruth"))
    with pytest.raises(ConfigError, match=r"q_W_B_wxyz \[3\.0, 0\.0, 0\.0, 0\.0\] has norm 3, "
                       r"not 1"):  # fmt: skip
        Navigator(cfg, Rig(), initial_state=InitialState(0, x, np.eye(18) * 1e-4))
    x[6:10] = [0.0, 0.0, 0.0, 0.0]
    with pytest.raises(ConfigError, match="has norm 0, not 1"):
        Navigator(cfg, Rig(), initial_state=InitialState(0, x, np.eye(18) * 1e-4))
    x[6:10] = [1.0, 0.0, 0.0, 0.0]
    x[0] = np.nan
    with pytest.raises(ConfigError, match="x holds a non-finite number"):
        Navigator(cfg, Rig(), initial_state=InitialState(0, x, np.eye(18) * 1e-4))
    with pytest.raises(ConfigError, match=r"x has 13 numbers, the state 19"):
        Navigator(cfg, Rig(), initial_state=InitialState(0, np.zeros(13), np.eye(12)))
    # a file's rounded digits are normalised
    x[0] = 0.0
    x[6:10] = [0.9999, 0.0, 0.0, 0.0]
    nav = Navigator(cfg, Rig(), initial_state=InitialState(1_000_000_000, x, np.eye(18) * 1e-4))
    _feed_static(nav, 0.5, np.random.default_rng(9))
    s = nav.state()
    assert s is not None and abs(np.linalg.norm(s.q_W_B_wxyz) - 1.0) < 1e-12


def test_stereo_pairs_fed_before_any_imu_sample_are_held_up_to_a_bound() -> None:
    """A user's probe: 60 s of pairs fed before the IMU grew the process by 824 MB and were
    then discarded uncounted. Beyond ``MAX_FRAMES_BEFORE_IMU`` they are dropped, counted."""
    from svains.navigation.navigator import MAX_FRAMES_BEFORE_IMU

    nav = Navigator(RunConfig(method="3d"), _stereo_rig())
    img = np.zeros((4, 6), np.uint8)
    img2 = img.copy()
    img2[0, 0] = 1
    for k in range(MAX_FRAMES_BEFORE_IMU + 25):
        nav.feed_stereo(500_000_000 + k * 50_000_000, img, img2)
    assert nav.queue.dropped == {"frame": 25}
    assert len(nav.queue.pending_after(0)) == MAX_FRAMES_BEFORE_IMU
    # fed tracks alike (a review)
    nav = Navigator(RunConfig(method="3d"), _stereo_rig())
    for k in range(MAX_FRAMES_BEFORE_IMU + 5):
        nav.feed_tracks(500_000_000 + k * 50_000_000, [1], [[10.0, 5.0]], [[4.0, 5.0]])
    assert nav.queue.dropped == {"frame": 5}
    # a repeated GPS stamp after close() is refused as any feed is, not dropped (a review)
    nav = Navigator(RunConfig(), _gps_rig())
    rng = np.random.default_rng(13)
    _feed_resting_with_fixes(nav, 3.0, rng, lambda t, _: nav.feed_gps(
        t, 0.3 * rng.standard_normal(3), np.zeros(3)))
    nav.close()
    with pytest.raises(ClosedError, match=r"feed_gps after close"):
        nav.feed_gps(1_500_000_000, np.zeros(3), np.zeros(3))  # a stamp fed before


@pytest.mark.parametrize("crossed", [False, True])
def test_fed_tracks_with_left_and_right_crossed_are_named_and_exchanged(
    crossed: bool, caplog: pytest.LogCaptureFixture
) -> None:
    """A user's probe: tracks fed right-then-left went unfused, 39 of 39 frames, with only "no
    vision fused" to say so. Judged over the first frames, warned once, exchanged."""
    nav = Navigator(RunConfig(method="3d"), replace(_stereo_rig(), imu_period_s=0.005))
    rng = np.random.default_rng(10)
    with caplog.at_level("WARNING", logger="svains.navigation.navigator"):
        for k in range(4):
            uv_l = rng.uniform(50, 600, (30, 2))
            uv_r = uv_l - [rng.uniform(2, 40), 0.0]  # positive disparity
            if crossed:
                uv_l, uv_r = uv_r, uv_l
            nav.feed_tracks(1_000 + k, np.arange(30), uv_l, uv_r)
    said = caplog.text.count("uv_left and uv_right look crossed; they are exchanged")
    assert said == int(crossed)
    frames = sorted(e for e in nav.queue._heap if e[1] == FRAME)
    # every frame queued with the left pixel right of the right one (disparity > 0) from the
    # verdict on (the third frame); before it, as fed
    for t, _, _, payload in frames[2:]:
        assert np.all(payload[2][:, 0] > payload[3][:, 0]), t


def test_close_checks_until_ns_as_the_feeds_check_stamps() -> None:
    nav = Navigator(RunConfig(), Rig())
    _feed_static(nav, 3.0, np.random.default_rng(11))
    with pytest.raises(ValueError, match=r"close: until_ns must be integer nanoseconds, got "
                       r"'abc'"):  # fmt: skip
        nav.close(until_ns="abc")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"got 1\.5 \(a time in seconds\? pass round"):
        nav.close(until_ns=1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"close: until_ns 2 is before \d+ ns, .* measurements "
                       r"\(a time in seconds\? pass round\(t_s \* 1e9\)\)"):  # fmt: skip
        nav.close(until_ns=2)
    assert nav.close(until_ns=np.int64(nav.history.last_ns)).t_ns[-1] == nav.history.last_ns


def test_a_second_gps_fix_with_the_same_stamp_is_dropped() -> None:
    nav = Navigator(RunConfig(), _gps_rig())
    rng = np.random.default_rng(12)

    def fix(t: int, _: int) -> None:
        p = 0.3 * rng.standard_normal(3)
        nav.feed_gps(t, p, np.zeros(3))
        nav.feed_gps(t, p + 1.0, np.zeros(3))  # the same instant, other values

    _feed_resting_with_fixes(nav, 4.0, rng, fix)
    res = nav.close()
    assert res.report["dropped"] == {"gps": 4}
