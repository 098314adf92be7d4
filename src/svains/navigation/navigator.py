"""``Navigator``: the online estimator, fed one measurement at a time (``svains.Navigator``).

Built from a ``RunConfig`` and the sensors' calibrations (``Rig``), never from a data set. Every
``feed_*`` call is synchronous: it finishes the work it releases. The IMU is the clock: a
measurement stamped t is processed once an IMU sample later than ``t + buffer.window_s`` has
arrived (``EventQueue``), so sensors up to the window late are put back in order; later ones are
dropped, counted (``report["dropped"]``) and warned about. Estimates are causal.

Processing order (the batch runner's, kept exactly): released measurements pass the input
stages in time order (magnetometer/sonar rate caps, ``frame_stride``, pairing of pre-tracked
features), then wait for the initial state (``Starter``); from then on each group of
measurements stamped at the same time t is fused after propagating the IMU exactly to t, ties
in the order GPS, magnetometer, sonar, vision frame, output tick. Output ticks lie on a grid of
``output_period_s`` anchored at 0 ns, each at the first IMU sample at or after its grid point.
"""

from __future__ import annotations

import collections
import logging
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import ClosedError, ConfigError, InitialisationError
from svains.models.state import BIASED, PAPER
from svains.navigation.clock_steps import ClockSteps
from svains.navigation.event_queue import FRAME, GPS, MAG, SONAR, EventQueue
from svains.navigation.fault_handling import ImuFaults, RateLimitedLog
from svains.navigation.imu_history import ImuHistory
from svains.navigation.init import InitialState
from svains.navigation.ins import InsFilter, default_imu_calib
from svains.navigation.navigator_core import Core, gps_off_windows
from svains.navigation.options import RunConfig
from svains.navigation.outputs import NavState, RunResult
from svains.navigation.platform_noise import StaticNoise, platform_noise
from svains.navigation.plausibility import SampleChecks, TrackSides
from svains.navigation.starter import Starter
from svains.navigation.tracks import TrackOptions
from svains.navigation.vision_sources import FeatureFrames, ImageFrames, rig_from_calibrations
from svains.navigation.zupt import StaticTest
from svains.sensors.types import Rig
from svains.sensors.units import (
    GRAVITY_RANGE_M_S2,
    accel_units_problem,
    declared_rate_unit_problem,
    time_unit_problem,
)

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)
# measurements this long after the last IMU sample at close() are on another clock
UNUSED_AFTER_NS = 1_000_000_000

_UNITS_SPAN_NS = 2_000_000_000  # IMU samples judged for the accelerometer's unit
_UNIT_SAMPLES = 20  # IMU samples whose spacing judges the stamps' unit

OutputCallback = Callable[[NavState], None]


# A gps or vision start this long (s) after the first IMU sample is warned: it skipped data.
START_WAIT_WARN_S = 5.0

# Frames (stereo pairs, tracks) held when fed before any IMU sample (a driver's images may
# start a little before its IMU); later ones are dropped, counted: 2 s at 20 Hz, 14 MB of
# 752x480 pairs.
MAX_FRAMES_BEFORE_IMU = 40

# States ``outputs()`` keeps undrained: 10 minutes at the default 10 Hz (3.7 kB each).
OUTPUTS_KEPT = 6000


class Navigator:
    """Causal estimator for ``config.method`` in {ins, lc, tc, 3d} (``vo`` has no filter).

    ``on_output(state)`` is called at every output tick (and for the final state); the same
    states can be drained with ``outputs()`` (the latest ``OUTPUTS_KEPT``; none kept with
    ``keep_outputs=False``). ``initial_state`` starts the filter from a given state
    (``init.mode == "groundtruth"``) instead of the IMU/GPS/vision start. ``rest_noise``: the
    platform's IMU white noise measured at rest before the run (``platform_noise.rest_noise``),
    which a start that is not static takes for the platform noise rule (a static start measures
    its own).
    """

    def __init__(
        self, config: RunConfig, rig: Rig, *, on_output: OutputCallback | None = None,
        initial_state: InitialState | None = None, keep_outputs: bool = True,
        rest_noise: StaticNoise | None = None,
    ) -> None:
        if not isinstance(config, RunConfig):
            raise TypeError(f"Navigator: config must be a RunConfig, got {type(config).__name__}"
                            " (svains.navigation.config_io.from_dict builds one from a mapping)")
        if not isinstance(rig, Rig):
            raise TypeError(f"Navigator: rig must be a Rig, got {type(rig).__name__}")
        if on_output is not None and not callable(on_output):
            raise TypeError(f"Navigator: on_output must be callable, got {on_output!r}")
        if config.method == "vo":
            raise ConfigError("method vo has no filter: use svains.replay (VO chain) instead")
        if config.method != "ins" and (rig.cam0 is None or rig.cam1 is None):
            # refused here: the frames would otherwise be dropped one by one and the run go on
            # inertial only under "no vision fused" (a probe)
            raise ConfigError(f"method {config.method} needs the cam0 and cam1 calibrations "
                              "(the rig's cam0 and cam1); without cameras use method ins")
        g = float(np.linalg.norm(rig.gravity_W))
        if not GRAVITY_RANGE_M_S2[0] <= g <= GRAVITY_RANGE_M_S2[1]:
            raise ConfigError(f"rig.gravity_W has magnitude {g:.4g} m/s², expected "
                              f"{GRAVITY_RANGE_M_S2[0]}-{GRAVITY_RANGE_M_S2[1]} (Earth)")
        if rig.imu_period_s <= 0:
            raise ConfigError(f"rig.imu_period_s must be positive, got {rig.imu_period_s}")
        self.config = config
        self.rig = rig
        self._rest_noise = rest_noise
        self._rest_used: StaticNoise | None = None  # the rest the noise rule took (``_start``)
        self._first_imu_ns: int | None = None  # the start's wait is counted from it
        self._frames_before_imu = 0  # frames fed before it (``MAX_FRAMES_BEFORE_IMU``)
        self._track_sides = TrackSides()
        self._gps_off: list[tuple[int, int]] = []  # the Core's no-GPS windows, from it
        self.layout = BIASED if config.model == "biased" else PAPER
        self._wall0 = time.perf_counter()
        R_B_S = None if rig.imu is None else rig.imu.T_B_S[:3, :3]
        self.history = ImuHistory(R_B_S)
        # The accelerometer's unit, judged once 2 s of samples are in, for a start from a given
        # state: the static and in-flight starts refuse a wrong unit themselves.
        self._units_checked = config.init.mode != "groundtruth"
        self.queue = EventQueue(config.buffer.max_pending)
        # the stamps of the last frames fed: a frame fed twice (a driver's repeated message)
        # paired with itself and broke every link after it, silently (a user's probe)
        self._frame_stamps: collections.deque[int] = collections.deque(maxlen=64)
        self._gps_stamps: collections.deque[int] = collections.deque(maxlen=64)  # the same
        self._checks = SampleChecks(
            None if rig.mag is None else float(np.linalg.norm(rig.mag.m_W))
        )
        self._window_ns = round(config.buffer.window_s * 1e9)
        if self._window_ns < 0:
            raise ConfigError(f"buffer.window_s must be >= 0, got {config.buffer.window_s}")
        gps_at_start = config.use_gps and not (
            any(a <= 0.0 < a + d for a, d in config.gps_outages)
            or (config.gps_until_s is not None and config.gps_until_s <= 0.0))
        if config.init.mode == "gps" and not gps_at_start:
            log.warning("init.mode gps takes the start from the GPS fixes, though the run fuses "
                        "none there (no GPS, or an outage from 0 s): the start is GPS-aided, "
                        "the rest is not")  # fmt: skip
        if config.zupt.enabled and config.zupt.after_start and config.method == "ins":
            # (set, not the default: None leaves ins its start's rest alone)
            log.warning("zupt.after_start with ins: the IMU's rest test alone also passes a "
                        "steady motion, and a zero velocity fused while moving takes the run "
                        "off (the vision methods have the camera as a second witness)")
        self.starter = Starter(config.init, rig, self.layout, initial_state,
                               gps_fused=config.use_gps and rig.gps is not None,
                               max_row_diff_px=config.vision.max_row_diff_px,
                               gps_velocity=config.use_gps_velocity,
                               local_heading_wait=(config.method != "ins"
                                                   and config.faults.heading_check))
        self._warn = RateLimitedLog(config.faults.warn_interval_s)
        self.clock = ClockSteps()
        # A rig without an IMU calibration is guarded with the default one the filter uses: a
        # non-finite sample fed online would otherwise reach the filter and end the run.
        guarded = rig if rig.imu is not None else replace(rig, imu=default_imu_calib())
        self.imu_faults = (
            ImuFaults(guarded, config.faults, self._warn,
                      StaticTest(config.zupt, config.init, float(np.linalg.norm(rig.gravity_W))))
            if config.faults.imu_guard
            else None
        )
        self._on_output = on_output
        # The states for ``outputs()``, the latest OUTPUTS_KEPT: a caller that takes them by
        # ``on_output`` (the replay) never drains them (134 MB per hour of 10 Hz states kept)
        self._outputs: deque[NavState] = deque(maxlen=OUTPUTS_KEPT if keep_outputs else 0)
        self._outputs_warned = False
        self._backlog: list[tuple[int, int, Any]] = []  # released before the initial state
        self._source: FeatureFrames | ImageFrames | None = None
        self._frames_seen = 0
        self._last_bin: dict[int, int] = {}
        self.core: Core | None = None
        self.status = "initialising"
        self._end_ns: int | None = None
        self._result: RunResult | None = None

    # ---- inputs -------------------------------------------------------------------------
    def feed_imu(self, t_ns: int, gyro_S: ArrayLike, accel_S: ArrayLike) -> None:
        """One IMU sample: ``gyro_S`` rad/s and ``accel_S`` specific force m/s² in the IMU frame
        S (``rig.imu.T_B_S`` rotates them to the body). Stamps must increase (duplicates and
        backward stamps are dropped, counted and warned about)."""
        t_ns = self.clock.imu(_stamp("feed_imu", t_ns), self.history.last_ns,
                              self._imu_period_ns, self._warn.origin_ns)
        self._on_imu(t_ns, _vector("feed_imu", "gyro_S", gyro_S),
                     _vector("feed_imu", "accel_S", accel_S))

    def _on_imu(self, t_ns: int, gyro_S: ArrayLike, accel_S: ArrayLike) -> None:
        # The one place IMU samples enter the estimator.
        if self.status == "closed":
            raise ClosedError("feed_imu after close(): this Navigator's run is over; make a "
                              "new Navigator for another")  # fmt: skip
        if self.status == "finished":  # past the configured duration: the stream may go on
            return
        if self._warn.origin_ns is None:
            self._warn.origin_ns = int(t_ns)  # warnings count seconds from here
        last = self.history.last_ns
        if last is not None and t_ns <= last:
            self.queue.drop("imu", t_ns, "stamp not after the previous IMU sample")
            return
        if self.imu_faults is not None and not self.imu_faults.accept(
            t_ns, gyro_S, accel_S, self.history, self.queue.horizon_ns
        ):
            return  # dropped: propagation bridges it from its neighbours
        self.history.append(t_ns, gyro_S, accel_S)
        if self._first_imu_ns is None:
            self._first_imu_ns = t_ns
            self._gps_off = gps_off_windows(self.config, t_ns)
        if self.history.n == _UNIT_SAMPLES and not self.history.dropped:  # judged once
            # stamps in µs or ms were blamed on a short static start (a user's probe)
            step = float(np.median(np.diff(self.history.t_ns)))
            unit = time_unit_problem(step)
            if unit is None and step > 0 and self.rig.imu is not None:
                unit = declared_rate_unit_problem(1e9 / step, float(self.rig.imu.rate_hz),
                                                  "the rig's IMU")  # fmt: skip
            if unit is not None:
                raise ConfigError(f"feed_imu: {unit} (feed_* take integer nanoseconds)")
        if not self._units_checked:
            self._check_units()
        horizon_ns = t_ns - self._window_ns
        hold_ns = None if self.imu_faults is None else self.imu_faults.hold_ns
        self._advance(horizon_ns if hold_ns is None else min(horizon_ns, hold_ns))

    def _check_units(self) -> None:
        # Online input never passes the readers' unit checks: an accelerometer in g or without
        # gravity is warned about once.
        t = self.history.t_ns
        if t.size < 2 or t[-1] - t[0] < _UNITS_SPAN_NS:
            return
        self._units_checked = True
        problem = accel_units_problem(self.history.accel_B, np.asarray(self.rig.gravity_W),
                                      self.history.gyro_B)  # fmt: skip
        if problem is not None:
            log.warning("over the first %.0f s of IMU samples %s", _UNITS_SPAN_NS * 1e-9,
                        problem)  # fmt: skip

    def feed_stereo(
        self, t_ns: int, left: NDArray[np.uint8], right: NDArray[np.uint8], copy: bool = True
    ) -> None:
        """A stereo pair (raw cam0/cam1 images, uint8: grey (H, W), or BGR/BGRA (H, W, 3|4)
        turned grey): the front end runs on it when the estimator reaches ``t_ns`` (camera
        clock = IMU clock); a pair of another size than the calibration's is dropped with a
        warning. The arrays are copied unless ``copy=False``, which hands them over: the caller
        must not change them afterwards. Ignored by ``ins`` but for an ``init.mode`` vision start.
        ``TypeError`` for another dtype:
        a 12- or 16-bit or float image has no one right conversion, so the caller makes it."""
        self._open("feed_stereo")
        if self._takes_frames:
            t_ns = self.clock.other(_stamp("feed_stereo", t_ns), "frame")
            left, right = _image("left", left), _image("right", right)
            for name, img in (("left", left), ("right", right)):
                dtype = img.dtype
                if dtype != np.uint8:
                    raise TypeError(
                        f"feed_stereo: the {name} image is {dtype}, not uint8: scale it to 8 "
                        "bits first (e.g. (img >> 4).astype(np.uint8) for 12-bit data, "
                        "(img >> 8) for 16-bit, (img * 255).astype(np.uint8) for floats in 0-1)"
                    )
            # Copied by default: drivers reuse their image buffers while the pair waits.
            pair = (np.array(left, np.uint8, copy=True), np.array(right, np.uint8, copy=True)) \
                if copy else (np.asarray(left, np.uint8), np.asarray(right, np.uint8))
            if np.array_equal(pair[0], pair[1]):
                # One camera's image sent twice (a driver or a launch file publishing cam0 on
                # both topics): zero disparity everywhere, all points at infinity (a user's
                # probe: ATE 0.16 -> 0.83 m with every 4th pair so, not a word).
                lo, hi = int(pair[0].min()), int(pair[0].max())
                self.queue.drop("frame", t_ns, "the left and right images are identical"
                                + (f": both blank, every pixel {lo} (a camera covered, off or "
                                   "not yet exposed?)" if lo == hi else
                                   " (one camera's image sent twice?)"))  # fmt: skip
                return
            if self._held_before_imu(t_ns):
                return
            if self._new_stamp(self._frame_stamps, "frame", "frame", t_ns):
                self._push(t_ns, FRAME, ("images", *pair))

    def feed_tracks(
        self, t_ns: int, track_id: ArrayLike, uv_left: ArrayLike, uv_right: ArrayLike
    ) -> None:
        """Pre-tracked features of one stereo frame: ``track_id`` (M,) int, ``uv_left``,
        ``uv_right`` (M, 2) px in the rectified pair ``cam0``/``cam1`` define. Ignored by
        ``ins``."""
        self._open("feed_tracks")
        if self._takes_frames:
            t_ns = self.clock.other(_stamp("feed_tracks", t_ns), "frame")
            raw = np.asarray(track_id)
            if raw.dtype.kind not in "iu" and not (
                    raw.dtype.kind == "f" and np.all(raw == np.round(raw))):  # fmt: skip
                raise ValueError(f"feed_tracks: track_id must hold integers, got {raw.dtype} "
                                 f"{raw.ravel()[:3].tolist()}")  # fmt: skip
            ids = raw.astype(np.int64)
            uv_l, uv_r = np.asarray(uv_left, float), np.asarray(uv_right, float)
            m = ids.shape[0] if ids.ndim == 1 else -1
            if m < 0 or uv_l.shape != (m, 2) or uv_r.shape != (m, 2):
                raise ValueError(
                    f"feed_tracks: track_id (M,), uv_left and uv_right (M, 2) expected, got "
                    f"{ids.shape}, {uv_l.shape}, {uv_r.shape}"
                )
            finite = np.isfinite(uv_l).all(axis=1) & np.isfinite(uv_r).all(axis=1)
            if not finite.all():
                # NaN or inf pixels (a tracker's lost features) were fused as numbers, with
                # numpy's warnings at best (a user's probe): dropped, counted.
                self.queue.drop("feature", t_ns, f"{int((~finite).sum())} of {m} "
                                "features with non-finite pixels")  # fmt: skip
                ids, uv_l, uv_r = ids[finite], uv_l[finite], uv_r[finite]
            crossed = self._track_sides.observe(uv_l, uv_r)
            if crossed is not None:
                # (fed tracks went unfused without a word: a user's probe)
                log.warning("feed_tracks: %s", crossed)
            if self._track_sides.crossed:
                uv_l, uv_r = uv_r, uv_l
            if self._held_before_imu(t_ns):
                return
            if self._new_stamp(self._frame_stamps, "frame", "frame", t_ns):
                self._push(t_ns, FRAME, ("features", ids, uv_l, uv_r))

    def feed_gps(self, t_ns: int, p_W_G: ArrayLike, v_W_G: ArrayLike | None = None) -> None:
        """A GPS fix: antenna position ``p_W_G`` (3,) m and velocity ``v_W_G`` (3,) m/s (None:
        position only) in the world frame."""
        # copies: a fix waits in the queue (and the start holds the first ones), while a
        # driver may reuse its buffers (every held fix read the newest: a user's probe)
        self._open("feed_gps")
        v = None if v_W_G is None else _vector("feed_gps", "v_W_G", v_W_G).copy()
        p = _vector("feed_gps", "p_W_G", p_W_G).copy()
        t_ns = self.clock.other(_stamp("feed_gps", t_ns), "gps")
        # two fixes of one instant were both fused, as if independent (a user's probe)
        if self._new_stamp(self._gps_stamps, "gps", "fix", t_ns):
            self._push(t_ns, GPS, (p, v))

    def feed_mag(self, t_ns: int, m_S: ArrayLike) -> None:
        """A magnetometer sample ``m_S`` (3,) Gauss in its sensor frame."""
        t_ns = self.clock.other(_stamp("feed_mag", t_ns), "mag")
        self._push(t_ns, MAG, _vector("feed_mag", "m_S", m_S).copy())

    def feed_sonar(self, t_ns: int, range_m: float) -> None:
        """A sonar range (m) along the sensor's +z axis to flat ground."""
        r = np.asarray(range_m, dtype=float) if not isinstance(range_m, float) else range_m
        if np.ndim(r) != 0:
            raise ValueError(f"feed_sonar: range_m must be one number, got shape {np.shape(r)}")
        self._push(self.clock.other(_stamp("feed_sonar", t_ns), "sonar"), SONAR, float(r))

    def _held_before_imu(self, t_ns: int) -> bool:
        """Whether the frame at ``t_ns`` is dropped, counted, as one too many fed before any IMU
        sample: nothing consumes frames until then (60 s of pairs held 824 MB and vanished
        uncounted once the IMU came: a user's probe)."""
        if self._first_imu_ns is not None:
            return False
        self._frames_before_imu += 1
        if self._frames_before_imu <= MAX_FRAMES_BEFORE_IMU:
            return False
        self.queue.drop("frame", t_ns, "fed before any IMU sample: the estimator holds at most "
                        f"{MAX_FRAMES_BEFORE_IMU} frames until the IMU starts (feed the IMU "
                        "first)")  # fmt: skip
        return True

    def _new_stamp(self, stamps: collections.deque[int], kind: str, noun: str,
                   t_ns: int) -> bool:  # fmt: skip
        """Whether no ``kind`` measurement (a ``noun``) with the stamp ``t_ns`` is among the
        latest ``stamps`` (then kept there), else dropped, counted."""
        if t_ns in stamps:
            self.queue.drop(kind, t_ns, f"a second {noun} with the same stamp; the first is kept")
            return False
        stamps.append(t_ns)
        return True

    def _open(self, method: str) -> None:
        """``ClosedError`` for a ``feed_*`` call after ``close()``."""
        if self.status == "closed":
            raise ClosedError(f"{method} after close(): this Navigator's run is over; make a "
                              "new Navigator for another")  # fmt: skip

    def _push(self, t_ns: int, kind: int, payload: Any) -> None:
        if self.status == "closed":
            raise ClosedError("a measurement fed after close(): this Navigator's run is over; "
                              "make a new Navigator for another")  # fmt: skip
        if self.status == "finished":
            return
        if self._end_ns is not None and t_ns > self._end_ns:
            return
        self.queue.push(t_ns, kind, payload)

    # ---- outputs ------------------------------------------------------------------------
    def state(self) -> NavState | None:
        """The current estimate (at the latest processed time), None before the start."""
        return None if self.core is None else self.core.snapshot()

    def outputs(self) -> Iterator[NavState]:
        """Drain the states produced at the output ticks since the last call (the latest
        ``OUTPUTS_KEPT``; older ones are dropped, warned once without ``on_output``)."""
        while self._outputs:
            yield self._outputs.popleft()

    @property
    def rest_noise(self) -> StaticNoise | None:
        """The IMU noise measured at rest that this run's noise rule took (its static start's,
        or the one given), None before the start or without one: a process restarted from
        ``state()`` passes it on (``Navigator(..., rest_noise=old.rest_noise)``), or the new run
        falls back to the calibration's densities."""
        return self._rest_used

    @property
    def t0_ns(self) -> int | None:
        """Time of the initial state (None before it)."""
        return None if self.core is None else self.core.t0_ns

    def close(self, until_ns: int | None = None) -> RunResult:
        """Process everything up to ``until_ns`` (default: the last IMU sample; at most the
        configured ``duration_s`` after the start) and return the run's ``RunResult``."""
        if self._result is not None:
            return self._result
        if until_ns is not None:
            until_ns = _stamp("close", until_ns, "until_ns")
        done = self.queue.horizon_ns
        if until_ns is not None and done is not None and until_ns < done - 1:
            # refused before anything changes: a later close() still ends the run
            seconds = " (a time in seconds? pass round(t_s * 1e9))" if (
                0 < until_ns < done // 100_000) else ""
            raise ValueError(f"close: until_ns {until_ns} is before {done - 1} ns, up to "
                             f"which the estimator has already processed its "
                             f"measurements{seconds}")
        last = self.history.last_ns
        if self.status != "finished" and last is not None:
            end = last if until_ns is None else min(int(until_ns), last)
            if self._end_ns is not None:
                end = min(end, self._end_ns)
            self._end_ns = end
            if self.core is not None:
                self.core.end_ns = end
            self._advance(end + 1)
            if self.core is None:
                odo = self.starter.odometry
                if odo is not None:  # a ``vision`` start: what its odometry had
                    n = len(odo.t_ns)
                    fix = ("no stereo frame came: are there images or features from this "
                           "start on?" if n == 0 else
                           "an earlier --start (the start needs 4 linked frames)" if n < 4 else
                           "an earlier --start, or a shorter window (--set "
                           "init.vision_window_s=...; 4 frames at least)")  # fmt: skip
                    raise InitialisationError(
                        f"in-flight start from vision: the stream ended before "
                        f"{self.config.init.vision_window_s:g} s of linked stereo frames (the "
                        f"last chain: {n} frames over {odo.span_s():.2f} s): {fix}")
                late = "" if not self.queue.late else (
                    "; dropped for coming more than buffer.window_s "
                    f"({self.config.buffer.window_s:g} s) after the IMU sample of their time: "
                    + ", ".join(f"{n} {kind}" for kind, n in self.queue.late.items())
                    + " measurement(s) (a longer window waits for them)")  # fmt: skip
                raise InitialisationError("the stream ended before the initial state was "
                                          f"decided: {self.starter.waiting_for(self.history)}"
                                          f"{late}")  # fmt: skip
            self._finish(end)
            if until_ns is None:
                self._warn_unused_after(end)
        if self.core is None:
            raise ConfigError("no IMU sample was fed: nothing to estimate")
        self.status = "closed"
        self._result = self.core.result(time.perf_counter() - self._wall0, self.queue.dropped)
        if self.clock.steps:
            self._result.report["clock_steps"] = list(self.clock.steps)
        return self._result

    def _imu_period_ns(self) -> int:
        """The IMU's sample spacing: the median of the last samples' (the rig's before)."""
        t = self.history.t_ns[-17:]
        if t.size >= 3:
            return int(np.median(np.diff(t)))
        return round(self.rig.imu_period_s * 1e9)

    # ---- processing ---------------------------------------------------------------------
    def _advance(self, horizon_ns: int) -> None:
        """Release and process every measurement stamped before ``horizon_ns``."""
        if self.queue.horizon_ns is not None and horizon_ns <= self.queue.horizon_ns:
            return
        if self._end_ns is not None:
            horizon_ns = min(horizon_ns, self._end_ns + 1)
        if len(self.queue):
            for t, kind, payload in self.queue.release(horizon_ns):
                self._stage(t, kind, payload)
        elif self.queue.horizon_ns is None or horizon_ns > self.queue.horizon_ns:
            self.queue.horizon_ns = horizon_ns
        if self.core is None:
            init = self.starter.try_start(self.history, self.queue.horizon_ns)
            if init is None:
                return
            self._start(init)
        assert self.core is not None
        if self._backlog:
            events, self._backlog = self._kept(self._backlog), []
            self.core.process(events, horizon_ns)
        elif self.core.tick_due(horizon_ns):
            self.core.process([], horizon_ns)
        if self._end_ns is not None and horizon_ns > self._end_ns:
            self._finish(self._end_ns)

    def _start(self, init: InitialState) -> None:
        measured = init.info.get("static_noise")
        # a start that is not static takes the rest the caller measured before it, if any
        rest = StaticNoise(**measured) if isinstance(measured, dict) else self._rest_noise
        self._rest_used = rest
        noise, decided = platform_noise(self.config.noise, self.rig.imu, rest)
        if decided is not None:
            if rest is self._rest_noise:
                decided["measured_at"] = "rest_noise"  # the replay: the recording's first rest
            init.info["imu_noise"] = decided
        if self._first_imu_ns is not None:
            # a start that waited (fixes inside a GPS outage, frames that would not link)
            # skipped the data before it without a word (a user's probe: 10 s)
            waited_s = (int(init.t_ns) - self._first_imu_ns) * 1e-9
            init.info["start_after_s"] = round(waited_s, 3)
            mode = self.config.init.mode
            if waited_s > START_WAIT_WARN_S and mode in ("gps", "vision"):
                needs = {"gps": "GPS fixes spaced for their noise",
                         "vision": "linked stereo frames"}[mode]
                self._warn.warn("start-wait", int(init.t_ns),
                                f"the {mode} start came {waited_s:.1f} s after the first IMU "
                                f"sample (it waits for {needs}): nothing before it is "
                                "estimated")  # fmt: skip
        ins = InsFilter(self.history, self.rig, self.layout, init, self.config.filter, noise)
        self.core = Core(self.config, self.rig, ins, init.info, self._source, self._emit,
                         self.imu_faults, self._warn,
                         lambda: sum(self.queue.dropped.get(s, 0) for s in ("frame", "feature")))
        if self.config.duration_s is not None:
            static_s = self.config.init.static_s
            if init.info.get("mode") == "static" and self.config.duration_s < static_s:
                log.warning("duration %.3g s is shorter than the static start's %.3g s: the "
                            "initial state read %.3g s of IMU at rest", self.config.duration_s,
                            static_s, static_s)  # fmt: skip
            end = int(init.t_ns) + int(self.config.duration_s * 1e9)
            self._end_ns = end if self._end_ns is None else min(end, self._end_ns)
        self.core.end_ns = self._end_ns
        self.status = "running"

    def _kept(self, events: list[tuple[int, int, Any]]) -> list[tuple[int, int, Any]]:
        """Measurements at or before the initial time are not fused (the input stages saw
        them), nor those after the end."""
        assert self.core is not None
        t0, end = self.core.t0_ns, self._end_ns
        kept = []
        for ev in events:
            if ev[0] > t0 and (end is None or ev[0] <= end):
                kept.append(ev)
            elif ev[1] == FRAME and self._source is not None:
                self._source.discard(ev[0])
        return kept

    def _warn_unused_after(self, end_ns: int) -> None:
        """Warn of measurements stamped more than a second after the last IMU sample: never
        used, most likely on another clock (a user's probe: frames an hour ahead made a pure
        INS run, with one "no vision fused" line)."""
        later = self.queue.pending_after(end_ns + UNUSED_AFTER_NS)
        if not later:
            return
        counts = collections.Counter(kind for _, kind in later)
        log.warning("%s stamped up to %.1f s after the last IMU sample were never used: on "
                    "another clock than the IMU's? (every stream is stamped on the IMU's "
                    "clock)", ", ".join(f"{n} {k}" for k, n in counts.items()),
                    (max(t for t, _ in later) - end_ns) * 1e-9)  # fmt: skip

    def _finish(self, end_ns: int) -> None:
        assert self.core is not None
        if self.status != "finished":
            self.core.finish(end_ns)
            self.status = "finished"

    def _emit(self, state: NavState) -> None:
        # (never full with keep_outputs=False: maxlen 0)
        if (len(self._outputs) == OUTPUTS_KEPT and self._on_output is None
                and not self._outputs_warned):  # fmt: skip
            self._outputs_warned = True
            log.warning("outputs() not drained for %d states: the oldest are dropped from it "
                        "(drain it more often, or take every state by on_output)",
                        OUTPUTS_KEPT)  # fmt: skip
        self._outputs.append(state)
        if self._on_output is not None:
            self._on_output(state)

    def _stage(self, t: int, kind: int, payload: Any) -> None:
        """Input stages on every released measurement, before the initial state's gate."""
        cfg = self.config
        if kind == GPS:
            why = self._checks.gps(*payload)
            if why is not None:
                self.queue.drop("gps", t, why)
                return
            if self.core is None:  # the start's fixes (all kept until it: ``Starter.add_gps``)
                self.starter.add_gps(t, *payload, off=self._gps_off_at(t))
            if not (cfg.use_gps and self.rig.gps is not None):
                return
        elif kind == MAG:
            why = None if self.rig.mag is None else self._checks.magnetometer(payload)
            if why is not None:  # neither the start's heading nor the filter may use it
                self.queue.drop("mag", t, why)
                return
            if not (cfg.use_mag and self.rig.mag is not None):
                return  # nor the start's heading: --no-mag is the advice for a disturbed one
            if self.core is None:  # the start's heading; kept after it, 74 MB per hour
                self.starter.add_mag(t, payload)
            if not self._rate_ok(MAG, t, cfg.max_mag_rate_hz):
                return
        elif kind == SONAR:
            if not (cfg.use_sonar and self.rig.sonar is not None):
                return
            why = self._checks.sonar(payload)
            if why is not None:
                self.queue.drop("sonar", t, why)
                return
            if not self._rate_ok(SONAR, t, cfg.max_sonar_rate_hz):
                return
        elif kind == FRAME:
            if self.core is None:
                self.starter.add_frame(t, payload)  # the ``vision`` start's odometry
            if cfg.method == "ins" or not self._frame_stage(t, payload):
                return
        self._backlog.append((t, kind, payload if kind != FRAME else None))

    def _gps_off_at(self, t: int) -> bool:
        """Whether the fix at ``t`` falls where the run fuses no GPS (``Core``'s windows)."""
        if not self.config.use_gps or self.rig.gps is None:
            return True
        return any(a <= t < b for a, b in self._gps_off)

    @property
    def _takes_frames(self) -> bool:
        """Frames are fused by the vision methods, and start every method with ``vision``."""
        return self.config.method != "ins" or self.config.init.mode == "vision"

    def _rate_ok(self, kind: int, t: int, max_rate_hz: float | None) -> bool:
        # Keep the first sample of each 1/max_rate bin (bins anchored at 0 ns, so streams
        # sampled on the same clock keep the same instants).
        if max_rate_hz is None:
            return True
        b = t // int(1e9 / max_rate_hz)
        prev = self._last_bin.get(kind)
        self._last_bin[kind] = b
        return prev is None or b != prev

    def _frame_stage(self, t: int, payload: tuple) -> bool:
        """``frame_stride`` over every frame; the tracks source; True if t is a vision event."""
        v = self.config.vision
        kind = payload[0]
        if self._source is None:
            if v.source not in ("auto", kind):
                self.queue.drop(kind, t, f"vision.source is {v.source}")
                return False
            self._source = self._make_source(kind)
            if self.core is not None:
                self.core.set_source(self._source)
        if self._source.kind != kind:
            self.queue.drop(kind, t, f"this run takes its tracks from {self._source.kind}")
            return False
        k = self._frames_seen
        self._frames_seen += 1
        if k % v.frame_stride:
            return False
        return self._source.push(t, *payload[1:])

    def _make_source(self, kind: str) -> FeatureFrames | ImageFrames:
        v = self.config.vision
        if kind == "images":
            return ImageFrames(self.rig.cam0, self.rig.cam1,
                               bundle=v.bundle_for(self.config.method))  # fmt: skip
        rig = rig_from_calibrations(self.rig.cam0, self.rig.cam1)
        track_opts = TrackOptions(max_row_diff_px=v.max_row_diff_px,
                                  egomotion=self.config.method == "lc",
                                  bundle=v.bundle_for(self.config.method),
                                  bundle_max_gap_s=v.bundle_max_gap_for(self.config.method),
                                  widen=True)  # fmt: skip
        return FeatureFrames(rig, track_opts)


__all__ = ["NavState", "Navigator", "RunResult"]


def _image(name: str, image: Any) -> NDArray[Any]:
    """A fed image as an array (H, W) or (H, W, 3|4); a driver's single-channel (H, W, 1) is
    taken as (H, W). ``TypeError`` naming the image for anything else."""
    a = image if isinstance(image, np.ndarray) else None
    if a is None:
        raise TypeError(f"feed_stereo: the {name} image must be a numpy array, got "
                        f"{type(image).__name__}")  # fmt: skip
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))) or min(a.shape[:2]) == 0:
        raise TypeError(f"feed_stereo: the {name} image must be (H, W) grey or (H, W, 3|4) "
                        f"colour, got shape {a.shape}")  # fmt: skip
    return a


def _stamp(method: str, t_ns: object, name: str = "t_ns") -> int:
    """``t_ns`` as int nanoseconds; ``ValueError`` naming ``method`` (and the argument
    ``name``) for a stamp that is not a whole number (seconds or milliseconds as floats were
    truncated to repeats of a few nanoseconds and dropped one by one: a user's probe)."""
    if type(t_ns) is int:
        return t_ns  # the replay's stamps: once per sample, so the short way
    if isinstance(t_ns, (bool, np.bool_)):
        raise ValueError(f"{method}: {name} must be integer nanoseconds, got {t_ns!r}")
    if isinstance(t_ns, (int, np.integer)):
        return int(t_ns)
    if not isinstance(t_ns, (float, np.floating)):
        raise ValueError(f"{method}: {name} must be integer nanoseconds, got {t_ns!r}")
    f = float(t_ns)
    if not np.isfinite(f) or f != round(f):
        hint = " (a time in seconds? pass round(t_s * 1e9))" if np.isfinite(f) else ""
        raise ValueError(f"{method}: {name} must be integer nanoseconds, got {f!r}{hint}")
    return int(f)


def _vector(method: str, name: str, value: ArrayLike) -> NDArray[np.float64]:
    """``value`` as a float (3,) array; ``ValueError`` naming ``method`` and ``name`` when it is
    another shape (a numpy broadcast error names neither). Non-finite values pass: the sample
    checks drop them, counted."""
    if type(value) is np.ndarray and value.shape == (3,) and value.dtype == np.float64:
        return value  # the replay's rows: once per IMU sample, so the short way
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{method}: {name} must hold 3 numbers, got {value!r}") from e
    if a.shape != (3,):
        raise ValueError(f"{method}: {name} must hold 3 values, got shape {a.shape}")
    return a

