"""``Core``: the running filter of a ``Navigator`` (after its initial state).

It receives the released measurements in time order, merges the output ticks, and processes
each same-time group: propagate the IMU exactly to t, fuse GPS/magnetometer/sonar in one
``update_blocks`` call (or stack them with the vision update, ``stack_with_vision``), run the
vision updater, log the state at ticks. ``_record`` is the one place where the outcome of every
measurement update is known.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from svains.errors import FilterError
from svains.filter.ukf import UpdateStats
from svains.models.state import BA, BG, Q, V
from svains.navigation.base import FrameContext, MeasurementBlock
from svains.navigation.camera_continuity import CameraContinuity, measured_motion, predicted_motion
from svains.navigation.course_check import CourseCheck, MagTurnCheck
from svains.navigation.event_queue import FRAME, GPS, MAG, SONAR, TICK
from svains.navigation.fault_handling import (
    LEAN_ROWS,
    ImuFaults,
    RateLimitedLog,
    Recovery,
    add_gap_covariance,
    whitened_correction,
)
from svains.navigation.gps_latency import GpsLatencyCheck
from svains.navigation.gps_whiteness import GpsWhiteness
from svains.navigation.heading_steps import HeadingSteps
from svains.navigation.ins import InsFilter, default_imu_calib
from svains.navigation.options import RunConfig
from svains.navigation.outputs import NavState, RunResult, UpdateRecord, WorldFrame
from svains.navigation.smoothing import history_recorder
from svains.navigation.sonar_anchor import ANCHOR_AGREE_M, ANCHOR_RANGES, anchor_height
from svains.navigation.still_camera import StillCamera
from svains.navigation.vision import LcUpdater, PixelUpdater, make_vision_updater
from svains.navigation.vision_clones import next_reference_ns
from svains.navigation.vision_gaps import (
    FramesSinceFused,
    vision_gap_limit_s,
    vision_gap_report,
)
from svains.navigation.vision_sources import FeatureFrames, ImageFrames, pixel_std_px
from svains.navigation.zupt import StaticTest, zero_velocity_block
from svains.sensors.types import Rig

log = logging.getLogger(__name__)


def gps_off_windows(config: RunConfig, t_first_ns: int) -> list[tuple[int, int]]:
    """The ``[from, to)`` ns windows where the run fuses no GPS: ``gps_outages`` and after
    ``gps_until_s``, both counted from the first IMU sample ``t_first_ns``."""
    off = [(t_first_ns + int(a * 1e9), t_first_ns + int((a + d) * 1e9))
           for a, d in config.gps_outages]  # fmt: skip
    if config.gps_until_s is not None:
        off.append((t_first_ns + int(config.gps_until_s * 1e9) + 1, 2**62))
    return off


# A given start faster than this (m/s) is not at rest, however uncertain its velocity.
START_REST_SPEED_MPS = 0.1
# A GPS fix refused with a NIS this many times its gate is warned (throttled): a glitch, or a
# lost estimate, not a fix a little off (multipath of 30 m on a 1.4 m fix: about 20 times).
FAR_FIX_GATES = 100.0


class Core(HeadingSteps):
    """Filter, vision updater, counters and the log of estimates (see the module docstring)."""

    def __init__(
        self, config: RunConfig, rig: Rig, ins: InsFilter, init_info: dict[str, object],
        source: FeatureFrames | ImageFrames | None, emit: Callable[[NavState], None],
        imu_faults: ImuFaults | None = None, warn: RateLimitedLog | None = None,
        frames_dropped: Callable[[], int] = lambda: 0,
    ) -> None:
        """``frames_dropped``: how many frames were dropped before they reached the core so
        far (the Navigator's queue: blank, late, ...), for the vision gap's warning."""
        self.config = config
        self.rig = rig
        self.ins = ins
        self.layout = ins.layout
        self.init_info = init_info
        self.t0_ns = int(ins.t_ns)
        # a start at the local origin (no GPS position): its height comes from the first ranges
        self._sonar_anchor = (rig.sonar is not None and config.use_sonar
                              and init_info.get("mode") in ("static", "vision")
                              and "position" not in init_info)  # fmt: skip
        self._first_ranges: list[float] = []
        self.end_ns: int | None = None
        self._emit = emit
        self._source = source
        self._updater: PixelUpdater | LcUpdater | None = None
        self._t_prev_frame: int | None = None
        self._period_ns = int(config.output_period_s * 1e9)
        self._next_grid = (self.t0_ns // self._period_ns + 1) * self._period_ns
        self._tick_cache = (-1, 0)  # (grid point, its tick time)
        self._gps_off = gps_off_windows(config, int(ins.t_imu[0]))
        self.counts: dict[str, dict[str, int]] = {}
        self.updates: list[UpdateStats] = []
        self.update_log: list[UpdateRecord] = []
        self.gps_outage_skipped = 0
        self._gps_block_ns: int | None = None  # the last fix offered (its spacing to the next)
        self.held_skipped = 0  # magnetometer samples not fused while it leaned (``hold``)
        self._log_t: list[int] = []
        self._log_x: list[np.ndarray] = []
        self._log_std: list[np.ndarray] = []
        self._log_P9: list[np.ndarray] = []
        self._warn = warn or RateLimitedLog(config.faults.warn_interval_s)
        self._imu_faults = imu_faults
        gps_used = bool(config.use_gps and rig.gps is not None)
        self._recovery = (Recovery(config.faults, self._warn, gps_used, self._bias_random_walk,
                                   heading_witness=config.method in ("lc", "tc", "3d"),
                                   clone_times=self._clone_times)
                          if config.faults.consistency else None)  # fmt: skip
        self._vision_fused_t: list[int] = []
        self._since_fused = FramesSinceFused()  # why vision stopped, with the gap's warning
        self._frames_dropped = frames_dropped
        self._vision_warned_gap = False
        # the last frames' spacings (ns): a gap is judged against the stream's own rate
        self._frame_spacing: collections.deque[int] = collections.deque(maxlen=31)
        self._continuity = CameraContinuity()
        self._next_keep_ns = self.t0_ns  # when ``_keep_imu`` runs next
        # An in-flight start (``init.mode`` gps or vision) has no start's rest to hold: a car
        # cruising passes the IMU's rest test, and with the wide velocity of a start from
        # position-only fixes the gate let "v = 0" in (KITTI raw: 4.7 m/s zeroed, NEES 3.6e4).
        # A given start (the ground truth, a Navigator's initial state) moving is none either:
        # straight flight at constant velocity passes the rest test, and one zero velocity let
        # in as the gate widened took a GPS-denied `ins` 214 m off (a user's probe). An
        # uncertain velocity is no sign of rest: 4.3 ± 1.5 m/s once passed as "within 3σ of
        # rest" and one zero fused on the cruising car took KITTI raw's `ins` 14 -> 111 m (a
        # review); a start given at rest but really moving is the user's to say.
        moving = float(np.linalg.norm(ins.ukf.x[V])) > START_REST_SPEED_MPS
        rest_start = config.init.mode not in ("gps", "vision") and not moving
        self._after_start = config.zupt.after_start_for(config.method)
        start_rest = self._after_start or rest_start
        self._zupt = (
            StaticTest(config.zupt, config.init, float(np.linalg.norm(rig.gravity_W)))
            if config.zupt.enabled and start_rest else None
        )
        self._next_zupt_ns = self.t0_ns
        # after the start's rest, a vision method's stops need the camera still too (built at
        # the first frame, from the vision updater's rig)
        self._still_wanted = (self._zupt is not None and self._after_start
                              and config.method != "ins")  # fmt: skip
        self._still: StillCamera | None = None
        self._start_rest_over = not rest_start  # a start in motion has none to hold
        self._rest_start = rest_start
        self._zupt_unwitnessed = 0  # IMU rests after the start that the camera saw moving
        # the camera's word on the start's rest (``zupt.start_camera``): when it ended it (ns),
        # and the zeros it loosened before
        self._start_vetoed_ns: int | None = None
        self._start_loosened = 0
        self.history = history_recorder(config, ins) if config.smoother.enabled else None
        # the GPS frame and the gyro's unit against each other (files are checked on load)
        self._course_check = CourseCheck(ins.history, rig.gravity_W) if gps_used else None
        # GPS innovations correlated from fix to fix: a wandering noise left undeclared
        self._gps_whiteness = (
            GpsWhiteness() if gps_used and rig.gps is not None
            and rig.gps.position_correlation_s <= 0.0 else None)  # fmt: skip
        # the GPS stamps against the IMU's clock (a receiver's latency)
        imu_calib = rig.imu or default_imu_calib()
        self._gps_latency = (
            GpsLatencyCheck(ins.history, np.asarray(rig.gravity_W, float), rig.gps.p_B_G,
                            rig.gps.velocity_noise_std, imu_calib.gyro_noise_density,
                            imu_calib.accel_noise_density)
            if gps_used and rig.gps is not None and config.faults.gps_latency_check else None
        )  # fmt: skip
        self._up_W = -np.asarray(rig.gravity_W, float) / np.linalg.norm(rig.gravity_W)
        self._init_heading(config, rig, init_info, gps_used)
        self._mag_off = False  # after a heading turn the magnetometer, which held it, is off
        # the magnetometer's axes against the IMU's (files are checked on load)
        self._mag_turn = (MagTurnCheck(ins.history, rig.mag.T_B_S[:3, :3])
                          if rig.mag is not None and config.use_mag else None)  # fmt: skip
        self._log()

    def _bias_random_walk(self) -> np.ndarray:
        """The filter's bias random-walk variances per second (6,): gyro, then accelerometer
        (read when needed: the platform noise rule may have changed them since the start)."""
        n = self.ins.noise
        return np.repeat([n.gyro_random_walk**2, n.accel_random_walk**2], 3)

    # ---- the event loop -----------------------------------------------------------------
    def _next_tick(self, horizon_ns: int) -> int | None:
        """Time of the next output tick if it is before ``horizon_ns`` (and the end)."""
        g = self._next_grid
        if g >= horizon_ns:
            return None
        if self._tick_cache[0] != g:
            t_imu = self.ins.t_imu
            k = int(np.searchsorted(t_imu, g))
            if k >= t_imu.size:
                return None
            self._tick_cache = (g, int(t_imu[k]))
        t = self._tick_cache[1]
        if t >= horizon_ns or (self.end_ns is not None and t >= self.end_ns):
            return None
        return t

    def tick_due(self, horizon_ns: int) -> bool:
        """Whether an output tick may lie before ``horizon_ns`` (cheap test)."""
        return self._next_grid < horizon_ns

    def _take_tick(self, t: int) -> None:
        # Grid points that snap to the same IMU sample give one tick.
        while self._next_grid <= t:
            self._next_grid += self._period_ns

    def process(self, events: list[tuple[int, int, Any]], horizon_ns: int) -> None:
        """Process ``events`` ((t_ns, kind, payload), in time order) and the ticks before
        ``horizon_ns``."""
        i, n = 0, len(events)
        while True:
            t_tick = self._next_tick(horizon_ns)
            t_ev = events[i][0] if i < n else None
            if t_ev is None and t_tick is None:
                return
            if t_ev is None or (t_tick is not None and t_tick < t_ev):
                assert t_tick is not None
                self._take_tick(t_tick)
                self._group(t_tick, [(TICK, None)])
                continue
            j = i
            while j < n and events[j][0] == t_ev:
                j += 1
            group = [(k, p) for _, k, p in events[i:j]]
            if t_tick == t_ev:
                self._take_tick(t_tick)
                group.append((TICK, None))
            self._group(t_ev, group)
            i = j

    def finish(self, end_ns: int) -> None:
        """The final state at ``end_ns`` (logged like a tick)."""
        self._propagate(end_ns)
        if self._heading_wait:
            self._take_path_heading(end_ns, "the run ended before the heading was known")
        self._log(last=True)
        if self._yaw_bank is not None:
            self._bank_gave_up(end_ns, "the run ended before the GPS fixes showed the "
                               "heading")  # fmt: skip
        if self._heading_wait and self.gps_held_heading:
            # the outputs hold the fix's position with the start's local heading (a probe)
            self._warn.warn("heading-wait", end_ns, "the run ended before the GPS "
                            f"gave the heading ({self.gps_held_heading} fix(es) held): its "
                            "outputs are in the start's local frame, turned from the world "
                            "about the start's GPS antenna")  # fmt: skip

    def _propagate(self, t: int) -> None:
        """The IMU to ``t``, with the noise of the IMU gaps crossed on the way."""
        self.ins.propagate_to(t)
        Q9 = self._imu_faults.take_noise(t) if self._imu_faults is not None else None
        if Q9 is not None:
            add_gap_covariance(self.ins.ukf, Q9)
        if self._yaw_bank is not None:
            self._bank_propagate(t, Q9)

    def _group(self, t: int, items: list[tuple[int, Any]]) -> None:
        ins, cfg = self.ins, self.config
        self._propagate(t)
        if self._recovery is not None and self._imu_faults is not None:
            fault_ns = self._imu_faults.last_fault_ns
            if fault_ns is not None:  # before the updates: a jump right after it is ours
                self._recovery.monitor.note_imu_fault(fault_ns)
        if self._zupt is not None and t >= self._next_zupt_ns:
            self._zero_velocity(t)
        blocks: list[MeasurementBlock] = []
        has_frame = has_tick = False
        for kind, payload in items:
            if kind == GPS:
                if any(a <= t < b for a, b in self._gps_off):
                    self.gps_outage_skipped += 1
                    continue
                assert self.rig.gps is not None
                if self._course_check is not None:
                    self._course_check.observe_fix(t, payload[1])
                if self._gps_latency is not None and payload[1] is not None:
                    self._observe_latency(t, payload[1])
                self._observe_gps_scale(t, payload[0], payload[1])
                use_v = cfg.use_gps_velocity and not (
                    self._recovery is not None and self._recovery.rate_off("gps", t))
                if (self._heading_check is not None and payload[1] is not None
                        and self._yaw_bank is None):  # (a bank weighs the headings itself)
                    self._check_heading(t, payload[0], payload[1], use_v)
                # a velocity not fused is not the wait's either: the fixes' path gives it
                v_wait = payload[1] if cfg.use_gps_velocity else None
                if self._heading_wait:
                    standing = self._wait_fix(t, payload[0], v_wait)
                    if self._heading_wait and self._hold_for_heading(t, standing):
                        continue
                recovery = self._acting_recovery
                if recovery is not None and recovery.reset_pending:
                    v = payload[1] if use_v else None
                    recovery.reset_from_gps(ins.ukf, self.rig.gps, payload[0], v)
                last, self._gps_block_ns = self._gps_block_ns, t
                block = ins.gps_block(self.rig.gps, payload[0], payload[1], use_v,
                                      None if last is None else (t - last) * 1e-9)
                if not self._bank_fix(t, block):
                    blocks.append(block)
            elif kind == MAG:
                assert self.rig.mag is not None
                if self._mag_turn is not None and self._mag_turn.observe(t, payload):
                    self._mag_off = True  # its field turns with the body: mirrored axes
                if self._recovery is not None and self._recovery.held("mag", t):
                    self.held_skipped += 1
                    continue
                if self._mag_off:  # or it held a heading the GPS velocities turned back
                    self.held_skipped += 1
                    continue
                blocks.append(ins.mag_block(self.rig.mag, payload))
            elif kind == SONAR:
                assert self.rig.sonar is not None
                if self._sonar_anchor:
                    self._anchor_height(t, payload)
                    if self._sonar_anchor:
                        continue  # the first ranges set the height: not fused against 0 m
                block = ins.sonar_block(self.rig.sonar, payload)
                if not self._bank_fix(t, block):
                    blocks.append(block)
            elif kind == FRAME:
                has_frame = True
            else:
                has_tick = True
        gate = cfg.filter.gate_probability
        if blocks and not (has_frame and cfg.filter.stack_with_vision):
            # Simultaneous measurements: one sigma-point draw, each gated on its own.
            offsets = self._recovery.monitor.jump_offsets(t) if self._recovery else None
            watched = self._recovery.watched if self._recovery else None
            for stats in ins.ukf.update_blocks(
                [(b.h, b.z, b.R, b.residual, b.name) for b in blocks], gate, offsets, watched
            ):
                self._record(stats, stats.name, t)
            blocks = []
        if has_frame:
            self._frame(t, blocks)
        for t_fix, v_fix in self._heading_fixes:
            assert self._heading_check is not None
            self._heading_check.after_update(t_fix, ins.ukf.x[V], v_fix)
        self._heading_fixes.clear()
        if self._own_fix_fused:  # the fix's pull is no motion of the antenna's own
            self._own_from_W_A = self._antenna_W()
            self._own_fix_fused = False
        recovery = self._acting_recovery
        if recovery is not None and (has_frame or blocks or len(items) > has_tick):
            recovery.check(ins.ukf, t)
        self._check_vision_gap(t)
        if t >= self._next_keep_ns:
            self._keep_imu(t)
        if has_tick:
            self._log()

    def _observe_gps_scale(self, t: int, p_W_G: Any, v_W_G: Any) -> None:
        """Hand a fix to the vision updater's baseline check, if it has one."""
        checks = getattr(self._vision_updater(), "checks", None)
        gps = self.rig.gps
        if checks is not None and gps is not None:
            checks.scale.observe_gps(t, np.asarray(p_W_G, float),
                              None if v_W_G is None else np.asarray(v_W_G, float), gps.p_B_G,
                              float(gps.position_noise_std), float(gps.velocity_noise_std))

    def _imu_fault_since(self, t_ns: int) -> bool:
        """Whether an IMU fault (a dropped sample, a bridged gap) came at ``t_ns`` or later:
        a step across it is no measured motion."""
        fault_ns = None if self._imu_faults is None else self._imu_faults.last_fault_ns
        return fault_ns is not None and fault_ns >= t_ns

    def _observe_latency(self, t: int, v_W_G: Any) -> None:
        """Hand a fix to the GPS latency check with the filter's attitude and biases before
        its update; a step across an IMU fault (a bridged gap) is not used."""
        assert self._gps_latency is not None
        x, last = self.ins.ukf.x, self._gps_latency.last_fix_ns
        usable = last is None or not self._imu_fault_since(last)
        zero = np.zeros(3)
        biased = self.ins.layout.biased
        self._gps_latency.observe_fix(t, v_W_G, x[Q], x[BG] if biased else zero,
                                      x[BA] if biased else zero, usable)  # fmt: skip

    def _anchor_height(self, t: int, range_m: float) -> None:
        """Once, after a start at the local origin: the local frame's height from the median of
        the first ``ANCHOR_RANGES`` sonar ranges (one no-echo or near-echo reading first set
        the height for the whole run: a user's probe), when most of them agree with it
        (``navigation.sonar_anchor``); logged and reported in ``init``."""
        assert self.rig.sonar is not None
        self._first_ranges.append(float(range_m))
        if len(self._first_ranges) < ANCHOR_RANGES:
            return
        self._sonar_anchor = False
        ranges = np.asarray(self._first_ranges)
        median = float(np.median(ranges))
        if np.sum(np.abs(ranges - median) <= ANCHOR_AGREE_M) <= ANCHOR_RANGES // 2:
            self._warn.warn("sonar-anchor", t, "the first sonar ranges disagree "
                            f"({', '.join(f'{r:.2f}' for r in ranges)} m): the start's height "
                            "is not taken from them")  # fmt: skip
            return
        ukf = self.ins.ukf
        got = anchor_height(ukf.x, ukf.P, ukf.manifold, self.rig.sonar,
                            np.asarray(self.rig.gravity_W, float), median)  # fmt: skip
        if got is None:
            return
        ukf.x, shift = got[0], got[1]
        # The frame moved, not the body: what was kept in the old heights moves with it (the
        # estimates logged since the start, a result's first states; keyframes stored).
        # Outputs already handed to an online caller keep the old heights.
        dp_W = shift * self._up_W
        for x in self._log_x:
            x[0:3] += dp_W
        reloc = getattr(self._updater, "relocaliser", None)
        if reloc is not None:
            reloc.memory.shift(dp_W)
        self.init_info["height_from_sonar_m"] = shift
        log.info("%.3f s into the run: the start's height set from the first sonar ranges "
                 "(moved %+.3f m along up)", (t - self.t0_ns) * 1e-9, shift)  # fmt: skip

    def _zero_velocity(self, t: int) -> None:
        """A zero-velocity update when the IMU shows the platform at rest (``navigation.zupt``);
        not while an IMU gap is bridged (its samples are not the platform's), and for ``ins``
        by default only until the start's rest ends (``zupt.after_start``): at its
        first motion or at an IMU gap."""
        assert self._zupt is not None
        self._next_zupt_ns = t + int(self.config.zupt.period_s * 1e9)
        if self._imu_faults is not None and self._imu_faults.bridging(t):
            # the platform may have set off inside the gap: the start's rest is over (a review:
            # a take-off inside a gap met IMU-only updates after it)
            self._start_rest_over = True
            if not self._after_start:
                # The start's rest cannot be followed across a gap: the platform may have set
                # off inside it (EuRoC: a take-off in a 5 s gap, then a steady climb that the
                # rest test passes and a wide post-gap gate let in: velocity NEES 4e3).
                self._zupt = None
            return
        if self._recovery is not None and self._recovery.bias_pending:
            # The alarm's step widened the velocity: a constant-velocity motion, which passes
            # the rest test, would pass the update's gate too (an analytic 3 m/s flight: v set
            # to 0 and the accelerometer bias to 1 m/s², the run lost).
            return
        rest = self._zupt.at_rest(self.ins.history, t)
        if rest and not self._start_rest_over and self._zupt.moved_since_start(
            self.ins.history, t
        ):
            rest = False  # set off gently: the block test alone would go on
        std = self._start_rest_std(t) if rest and not self._start_rest_over else None
        if std == float("inf"):
            rest = False  # the camera saw it creep: the IMU's limits pass a creep
            self._start_vetoed_ns = t
        if not rest:
            if rest is not None:
                self._start_rest_over = True
                if not self._after_start:
                    self._zupt = None  # the start's rest is over
            return
        std = self._zero_velocity_std(t) if std is None else std
        if std is None:
            self._zupt_unwitnessed += 1  # a steady motion passes the IMU's test
            return
        b = zero_velocity_block(std)
        (stats,) = self.ins.ukf.update_blocks([(b.h, b.z, b.R, b.residual, b.name)],
                                              self.config.filter.gate_probability)  # fmt: skip
        self._record(stats, "zupt", t)

    def _start_rest_std(self, t: int) -> float | None:
        """The camera's word on the start's rest at ``t`` (``StillCamera.start_rest_std``: inf
        where it ends it, a loosened standard deviation, or None), for the vision methods with
        ``zupt.start_camera``."""
        o = self.config.zupt
        if not (o.start_camera and self._still_wanted and self._still is not None):
            return None
        std = self._still.start_rest_std(t, o.velocity_std_mps)
        self._start_loosened += std is not None and std != float("inf")
        return std

    def _zero_velocity_std(self, t: int) -> float | None:
        """The standard deviation (m/s) of a rest the IMU's test passed at ``t``, or None where
        the camera does not confirm one after the start's rest (``navigation.still_camera``)."""
        o = self.config.zupt
        if not (self._start_rest_over and self._still_wanted):
            return o.velocity_std_mps
        bound = None if self._still is None else self._still.speed_bound(t)
        if bound is None or bound > o.still_max_speed_mps:
            return None
        # the camera's newest frame is older than t: the IMU says whether it set off since
        assert self._zupt is not None and self._still is not None
        t_frame = self._still.last_frame_ns
        if t_frame is not None and t_frame < t and self._zupt.moved_since(
                self.ins.history, t_frame, t, self.ins.noise.accel_noise_density):
            return None
        # no surer of the rest than the camera is: a third of its bound let a creep of 2-4 cm/s
        # in as zero, one update after another (velocity NEES 3.5 -> 13.8)
        return max(o.velocity_std_mps, bound)

    def _frame(self, t: int, blocks: list[MeasurementBlock]) -> None:
        ins, cfg = self.ins, self.config
        updater = self._vision_updater()
        if updater is None:
            return
        bridging = self._imu_faults is not None and self._imu_faults.bridging(t)
        long = (self._t_prev_frame is not None and cfg.vision.iterate_after_s is not None
                and (t - self._t_prev_frame) * 1e-9 > cfg.vision.iterate_after_s)  # fmt: skip
        ctx = FrameContext(ins.ukf, self.layout, t, self._t_prev_frame,
                           cfg.filter.gate_probability, blocks,
                           self._vision_apply(bridging, long),
                           (bridging and cfg.faults.gap_vision_two_view)
                           or (long and cfg.vision.two_view_after_long))  # fmt: skip
        # the calibration checks are the built-in updaters' (``VisionUpdater`` asks for none)
        checks = getattr(updater, "checks", None)
        if checks is not None and self._recovery is not None and self._recovery.lost:
            checks.filter_lost = True
        lean = self._recovery is not None and self._recovery.tests_vision(cfg.method)
        prior = (ins.ukf.x.copy(), ins.ukf.P[np.ix_(LEAN_ROWS, LEAN_ROWS)]) if lean else None
        ins.add_omega_white()  # paper model: the vision models see ω's gyro white noise
        x_before, P_before = ins.ukf.x.copy(), ins.ukf.P.copy()
        try:
            stats = updater.update(ctx)
        except (np.linalg.LinAlgError, FilterError) as exc:
            # A geometry the frame's model did not foresee (numpy's solver on a degenerate
            # feature), or a solve the frame's own numbers broke (the information form's
            # capacitance, indefinite by cancellation under a prior 1e7 times the pixel noise:
            # `--rotation imu` lost at frames 3 s apart stopped with exit 1, a user's probe),
            # loses that frame, not the run; a filter already changed cannot be.
            if not (np.array_equal(ins.ukf.x, x_before) and np.array_equal(ins.ukf.P, P_before)):
                raise
            updater.counters.frames_failed_numerics += 1
            self._warn.warn("vision-numerics", t, f"{cfg.method}: frame skipped, its update "
                            f"failed numerically ({exc})")  # fmt: skip
            stats = None
        finally:
            ins.remove_omega_white()
        if self._still_wanted and isinstance(updater, (PixelUpdater, LcUpdater)):
            # the built-in updaters keep their tracks; another ``VisionUpdater`` gives no witness
            if self._still is None:
                self._still = StillCamera(
                    updater.rig, pixel_std_px(cfg.vision.pixel_noise_std, updater.source),
                    cfg.zupt.window_s)  # fmt: skip
            self._still.observe(updater.last_tracks)
        if prior is not None and stats is not None and stats.accepted:
            # The bias test of vision updates (``faults.bias_test_vision_probability``): their
            # corrections, whitened, lean one way after an IMU bias step.
            w = whitened_correction(ins.ukf, *prior, LEAN_ROWS)
            if w is not None:
                stats = dataclasses.replace(stats, whitened=w)
        if (stats is not None and self._recovery is not None
                and self._recovery.monitor.tests_jumps(cfg.method)):  # fmt: skip
            self._judge_continuity(updater, ctx, stats, t)
        if hasattr(updater, "after_frame"):
            updater.after_frame(ctx)  # pose clones (rotation="clone")
        self._note_frame(t)
        if stats is not None:
            self._record(stats, cfg.method, t)
        if stats is None or not stats.accepted:
            self._since_fused.not_fused(refused=stats is not None)
        if self._t_prev_frame is not None:
            self._frame_spacing.append(t - self._t_prev_frame)
        self._t_prev_frame = t

    def _judge_continuity(
        self, updater: PixelUpdater | LcUpdater, ctx: FrameContext, stats: UpdateStats, t: int
    ) -> None:
        """A refused frame whose camera carried on the motion the last fused frame agreed on,
        while the filter's prediction left it, is the filter's error (an IMU fault the IMU
        checks missed), not a jump of the camera (``navigation.camera_continuity``)."""
        tr = updater.last_tracks
        if stats.accepted:
            self._continuity.fused(t, predicted_motion(ctx, updater.clones, updater.rig, tr))
            return
        if tr is None:
            return
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        if not self._continuity.may_judge(t, dt_s):
            return
        ego = updater.last_egomotion()
        predicted = predicted_motion(ctx, updater.clones, updater.rig, tr)
        if ego is None or predicted is None:
            return
        measured, std = measured_motion(ego, dt_s)
        if self._continuity.filter_moved(measured, std, predicted):
            assert self._recovery is not None and self._continuity.agreed_ns is not None
            self._recovery.monitor.note_filter_moved(self.config.method, t)
            # The IMU's samples since the last fused frame are suspect: the calibration checks
            # leave them out (they named a camera clock 300 ms off for such a burst).
            self.ins.history.mark_fault(self._continuity.agreed_ns, t)
            self._warn.warn("vision-filter-moved", t, f"{self.config.method}: the frame's camera "
                            "motion carries on the last fused frame's and the filter's "
                            "prediction left it: the filter is off (an IMU fault the IMU checks "
                            "missed?), not the camera")  # fmt: skip

    def _vision_apply(
        self, bridging: bool, long: bool = False
    ) -> Callable[[list[MeasurementBlock]], UpdateStats]:
        """How a vision update is applied. While the prediction rests on an IMU gap's bridge
        (``bridging``) it is linearised ``faults.gap_vision_iterations`` times and gated at
        ``faults.gap_vision_gate_probability``: the bridge's error is not Gaussian, and the
        frames are then the only evidence of the motion. A frame more than
        ``vision.iterate_after_s`` after the previous one (``long``) is linearised
        ``vision.long_iterations`` times: its prior is wide against the pixels too."""
        ins, cfg = self.ins, self.config
        n = cfg.vision.update_iterations
        if bridging:
            n = max(n, cfg.faults.gap_vision_iterations)
        if long:
            n = max(n, cfg.vision.long_iterations)

        def apply(blocks: list[MeasurementBlock]) -> UpdateStats:
            # tc/3d gate their features one by one and test the frame on how many pass
            # (``VisionOptions``); a stacked frame is tested whole only on request, or when
            # other sensors' blocks ride along (``filter.stack_with_vision``).
            alone = len(blocks) == 1 and blocks[0].name in ("vision_tc", "vision_3d")
            gate = cfg.vision.frame_gate_probability if alone else cfg.filter.gate_probability
            if bridging and gate is not None:
                gate = max(gate, cfg.faults.gap_vision_gate_probability)
            custom = any(b.residual for b in blocks)  # iterated updates need plain residuals
            return ins.apply(blocks, gate, 1 if custom else n,
                             cfg.vision.frame_max_nis_per_dof if alone else None)  # fmt: skip

        return apply

    def _keep_imu(self, t: int) -> None:
        """Let the IMU history drop what nothing can reach any more: samples more than
        ``buffer.imu_keep_s`` before the oldest of now, the previous frame and the front end's
        reference frame (re-checked once a second)."""
        keep_s = self.config.buffer.imu_keep_s
        self._next_keep_ns = t + 1_000_000_000
        if keep_s is None:
            return
        oldest = t if self._t_prev_frame is None else min(t, self._t_prev_frame)
        if self._source is not None:
            ref = next_reference_ns(self._source, t)
            oldest = oldest if ref is None else min(oldest, ref)
        # The gap covariance reads the signal's spread before a gap (``faults.gap_spread_s``).
        keep_s = max(keep_s, self.config.faults.gap_spread_s)
        self.ins.history.keep_from_ns = oldest - int(keep_s * 1e9)

    def _clone_times(self) -> tuple[int, ...]:
        """Times (ns) of the pose clones in the state, in state order (none: ())."""
        clones = getattr(self._updater, "clones", None)
        return tuple(clones.times) if clones is not None else ()

    def _vision_updater(self) -> PixelUpdater | LcUpdater | None:
        if self._updater is None and self._source is not None:
            self._updater = make_vision_updater(self.config.method, self.config.vision,
                                                self._source, self.ins.history, self.rig)
        return self._updater

    def set_source(self, source: FeatureFrames | ImageFrames) -> None:
        self._source = source

    @property
    def _acting_recovery(self) -> Recovery | None:
        """The consistency monitor where it acts: not while a bank of headings runs (the
        filter is then its likeliest copy, written over at each fix)."""
        return self._recovery if self._yaw_bank is None else None

    def _record(self, stats: UpdateStats, key: str, t: int) -> None:
        # The one place where every measurement update's outcome is known.
        c = self.counts.setdefault(key, {"fused": 0, "rejected": 0})
        c["fused" if stats.accepted else "rejected"] += 1
        if key == "gps" and not stats.accepted and stats.nis > FAR_FIX_GATES * stats.gate:
            # a fix 1 km off was refused and counted without a word (a user's probe)
            self._warn.warn("gps-far", t, f"a GPS fix refused {stats.nis / stats.gate:.0f} "
                            f"times beyond its gate (NIS {stats.nis:.3g}): the fix, or the "
                            "estimate, is far off")  # fmt: skip
        if (key == "gps" and stats.accepted and stats.whitened is not None
                and self._gps_whiteness is not None):  # fmt: skip
            said = self._gps_whiteness.observe(t, stats.whitened[:3])
            if said is not None:
                self._warn.warn("gps-whiteness", t, said)
        recovery = self._acting_recovery
        if recovery is not None and key != "zupt":
            # A refused zero-velocity update means motion, not a lost filter.
            recovery.observe(stats, key, t)
        # kept for the outputs without its arrays: a magnetometer update's share of the joint
        # update alone (``contribution``, 5.9 kB) made 214 MB per hour (a user's probe)
        slim = dataclasses.replace(stats, whitened=None, residual=None, innovation_cov=None,
                                   contribution=None)  # fmt: skip
        self.updates.append(slim)
        self.update_log.append(UpdateRecord(int(self.ins.t_ns), key, slim))  # filter is at t
        if key == self.config.method and stats.accepted:
            self._vision_fused_t.append(t)
            self._since_fused.fused(self._status_counts(), self._frames_dropped())
            self._vision_warned_gap = False

    def _check_vision_gap(self, t: int) -> None:
        """Warn once per stretch without fused vision longer than ``faults.vision_max_gap_s``,
        or than 2.5 frame spacings (``vision_gaps.vision_gap_limit_s``, of the last 31) where
        frames come further apart (a user's every 25th frame, 5 s: a warning at every frame
        said nothing)."""
        if self.config.method == "ins" or self._vision_warned_gap:
            return
        since = self._vision_fused_t[-1] if self._vision_fused_t else self.t0_ns
        gap_s = (t - since) * 1e-9
        if gap_s > self._vision_gap_limit_s():
            self._vision_warned_gap = True
            reasons = self._since_fused.reasons(self._status_counts(), self._frames_dropped())
            self._warn.warn("vision-gap", t, f"{self.config.method}: no vision fused for "
                            f"{gap_s:.1f} s: the estimate is inertial only"
                            f"{reasons}")  # fmt: skip

    def _vision_gap_limit_s(self) -> float:
        """The longest stretch (s) without fused vision that is no gap: the floor
        (``faults.vision_max_gap_s``, which a replay raises to 2.5 of its recording's frame
        spacings), or 2.5 of the recent frame spacings (``vision_gaps.vision_gap_limit_s``)."""
        return vision_gap_limit_s(self._frame_spacing, self.config.faults.vision_max_gap_s)

    def _status_counts(self) -> dict[str, int]:
        """The image front end's per-frame status counts so far (none for recorded features)."""
        return getattr(self._source, "status_counts", None) or {}

    def _fault_report(self, t_start_ns: int, t_end_ns: int) -> dict[str, Any]:
        """``imu_faults``, ``recovery`` and, for vision methods, the ``vision_gaps`` keys."""
        out: dict[str, Any] = {}
        if self._imu_faults is not None:
            out["imu_faults"] = self._imu_faults.summary()
        if self._recovery is not None:
            out["recovery"] = self._recovery.summary()
        if self.config.method != "ins":
            # the warning's limit: frames 7 s apart read "vision_gap_fraction 1.0" with 15 of
            # 20 frames fused against the 2 s floor (a user's probe)
            out.update(vision_gap_report(self._vision_fused_t, t_start_ns, t_end_ns,
                                         self._vision_gap_limit_s()))  # fmt: skip
        return out

    # ---- outputs ------------------------------------------------------------------------
    def snapshot(self) -> NavState:
        # The navigation block only (pose clones, when the state holds any, are left out).
        nx, ndx = self.layout.nx, self.layout.ndx
        x, P, _ = self._estimate()
        return NavState.from_state(self.ins.t_ns, x[:nx], P[:ndx, :ndx], self.layout,
                                   not self._heading_wait and self._yaw_bank is None)  # fmt: skip

    def _log(self, last: bool = False) -> None:
        ins = self.ins
        x, P, std = self._estimate()
        if self.history is not None:
            # (a bank of headings' estimate, not its filter's: a review found the smoothed
            # yaw σ the start's 28° where the logged one was 104°)
            self.history.mark(ins.t_ns, x, P, last=last)
        self._log_t.append(ins.t_ns)
        self._log_x.append(x[: self.layout.nx].copy())
        self._log_std.append(std)
        self._log_P9.append(P[:9, :9].copy())
        self._emit(self.snapshot())

    def _world_frame(self) -> WorldFrame:
        if self.init_info.get("mode") == "groundtruth":
            return "groundtruth"
        # A static start sets roll and pitch from gravity only; GPS fixes tie position (and,
        # through the trajectory, yaw) to the world frame.
        return "gps" if self.counts.get("gps", {}).get("fused", 0) > 0 else "local"

    def result(self, wall_s: float, dropped: dict[str, int]) -> RunResult:
        """The run's logged estimates and its report (no accuracy keys)."""
        cfg = self.config
        t = np.array(self._log_t, dtype=np.int64)
        res = RunResult(
            t, np.array(self._log_x), np.array(self._log_std), np.array(self._log_P9), {},
            self.updates, self.update_log, getattr(self._source, "track_log", None),
            world_frame=self._world_frame(),
            gps_used=bool(cfg.use_gps and self.rig.gps is not None), history=self.history,
            frame_turns=list(self.frame_turns),
        )  # fmt: skip
        duration = (t[-1] - t[0]) * 1e-9
        t_imu = self.ins.t_imu
        report: dict[str, Any] = {
            "method": cfg.method,
            "model": cfg.model,
            "init": self.init_info,
            "wall_s": wall_s,
            "data_duration_s": duration,
            "realtime_factor": duration / wall_s if wall_s > 0 else None,
            "imu_steps": int(np.searchsorted(t_imu, t[-1], "right"))
            - int(np.searchsorted(t_imu, t[0])),
            "measurements": self.counts,
            # the ticks fall on IMU samples: an output period below their spacing gives the
            # IMU's rate (1 ms asked on a 100 Hz IMU: 100 Hz written, 1000 reported before)
            "states_rate_hz": (min(1.0 / cfg.output_period_s,
                                   (t.size - 1) / ((int(t[-1]) - int(t[0])) * 1e-9))
                               if t.size > 2 and t[-1] > t[0] else 1.0 / cfg.output_period_s),
        }
        if dropped:
            report["dropped"] = dict(dropped)
        if self.gps_outage_skipped:
            report["gps_outage_fixes_skipped"] = self.gps_outage_skipped
        if self.held_skipped:
            report["mag_held_skipped"] = self.held_skipped
        if self.gps_held_heading:
            report["gps_held_for_heading"] = self.gps_held_heading
            # a wait that ended without a heading (the run's end) held them too (a probe)
            self.init_info.setdefault("gps_fixes_held", self.gps_held_heading)
        if self._course_check is not None:
            report["gps_course_check"] = self._course_check.summary()
        if self._gps_latency is not None:
            report["gps_latency_check"] = self._gps_latency.summary()
        if self._gps_whiteness is not None:
            report["gps_whiteness"] = self._gps_whiteness.summary()
        if self._heading_check is not None:
            report["heading_check"] = self._heading_check.summary()
        if self._mag_turn is not None:
            report["mag_turn_check"] = self._mag_turn.summary()
        if self._still_wanted:
            # rests the IMU's test passed after the start and the camera did not (or could not
            # tell): no update tried
            report["zupt_camera_not_still"] = self._zupt_unwitnessed
            if self.config.zupt.start_camera and self._rest_start:  # (a start's rest to end)
                report["zupt_start_camera"] = {
                    "ended_s": None if self._start_vetoed_ns is None
                    else (self._start_vetoed_ns - self.t0_ns) * 1e-9,
                    "loosened": self._start_loosened,
                }
        if self._gps_off:
            # Configured windows without GPS (int64 ns, [start, end)): the accuracy step reports
            # the error inside them as it does for gaps in the GPS stream.
            report["gps_off_windows_ns"] = [[int(a), int(b)] for a, b in self._gps_off]
        updater = self._vision_updater()
        if updater is not None and hasattr(updater, "summary"):
            # Vision counters: frames fused/rejected, features gated (see the updater's summary).
            report["vision"] = updater.summary()
        report.update(self._fault_report(int(t[0]), int(t[-1])))
        res.report = report
        return res
