"""Sensor-fault handling of the ``Navigator``: the IMU guard and the consistency recovery wired in.

- :class:`ImuFaults` (Navigator side): every IMU sample passes ``ImuGuard``; a dropped sample
  never reaches the ``ImuHistory`` (propagation bridges it by interpolating its neighbours); a
  gap's noise (``imu_guard.gap_covariance``'s model, sized by the sample spread before it) is
  added as the filter propagates across it (:meth:`ImuFaults.take_noise`).
- :class:`Recovery` (Core side): every gated update goes to ``ConsistencyMonitor``; its
  actions are applied to the filter: ``inflate`` scales the p/v/θ block of P (cross terms by
  the square root, so P stays positive semi-definite); ``reset`` re-initialises position and
  velocity from the next GPS fix (lever arm through the current attitude).

Each event is logged as a warning, at most one per kind per ``warn_interval_s`` of data time
(the rest are counted in the next warning). Counters go to ``report.json`` (``imu_faults``,
``recovery``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from svains.filter import chi2_gate
from svains.filter.ukf import UKF, UpdateStats
from svains.models.clones import CloneManifold
from svains.models.gps import gps_position, gps_velocity
from svains.models.state import DBA, DBG, DP, DTH, DV, P, V
from svains.navigation.bias_recall import (
    BiasAlarm,
    bias_change_nis,
    drop_step,
    inject_step,
    undo_step,
)
from svains.navigation.consistency import ConsistencyMonitor, ConsistencyOptions, RecoveryAction
from svains.navigation.imu_guard import ImuGuard, ImuGuardOptions
from svains.navigation.imu_history import ImuHistory
from svains.navigation.options import FaultOptions
from svains.navigation.unfuse import LeanShares, unfuse
from svains.navigation.zupt import StaticTest
from svains.sensors.types import GpsCalib, Rig

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)
# s, blocks whose means give the signal's spread before a gap (bench/faults.py, 5 s gap, 3d:
# 0.1 s blocks gave 1.68x the clean RMSE, 0.25 s 1.27x; raw samples, white noise included, 4.1x)
_BLOCK_S = 0.25
_AFTER_GAP_NS = 1_000_000_000  # after a gap, the time the prediction still counts as bridged
# s of samples the line through the bridge's first end point is fitted to (less than the
# Navigator's 0.1 s reordering window, so the filter has not reached that sample yet)
_FIT_S = 0.09
# s, a gap at least this long is bridged between window means at both ends (``_FIT_S`` of
# samples before and after it) instead of single samples: held over seconds, one sample's
# vibration is integrated as motion (EuRoC, rotors on, 5 s gap: 31 m after 10 s with the raw
# post-gap sample, see ``ImuFaults.accept``)
_LONG_GAP_S = 0.5
_FIT_NS = round(_FIT_S * 1e9)
_HOLD_END_NS = 1_000_000  # a held rest ends this long before the gap's first sample
# A pending bias alarm is decided when the test's sensors (GPS, and the vision updates where
# they feed the test) have been silent this long (an outage: nothing can confirm a step there,
# and the INS should cross it on the biases known before the alarm)
_ANCHOR_SILENT_NS = 2_000_000_000
# δv and δθ: the rows whose corrections a bias step makes lean (``whitened_correction``)
LEAN_ROWS = np.arange(DV.start, DTH.stop)
NAV9 = slice(0, 9)  # δp, δv, δθ in the tangent space (``models.state``)


# A kind that keeps recurring is warned at doubling intervals, up to this many base intervals
# (a GPS jump to the end of a run said the same line every second: 20 lines, a saturating IMU
# 129: a user's probe); quiet for EPISODE_GAP base intervals, it starts over (warned at once).
MAX_BACKOFF = 64
EPISODE_GAP = 10


class RateLimitedLog:
    """Warnings at most once per ``interval_ns`` of data time per kind, the interval doubling
    while the kind keeps recurring (``MAX_BACKOFF``, ``EPISODE_GAP``); the rest are counted.
    Each is stamped in seconds from ``origin_ns`` (the first IMU sample fed, set by the
    Navigator: the time ``--start`` and ``--gps-outage`` count in) when it is set."""

    def __init__(self, interval_s: float) -> None:
        self._interval_ns = int(interval_s * 1e9)
        self._last: dict[str, int] = {}  # the last warning's time per kind
        self._seen: dict[str, int] = {}  # the last event's time per kind, warned or not
        self._factor: dict[str, int] = {}  # the current interval in base intervals
        self._suppressed: dict[str, int] = {}
        self.origin_ns: int | None = None

    def warn(self, kind: str, t_ns: int, message: str) -> None:
        last, seen = self._last.get(kind), self._seen.get(kind)
        factor = self._factor.get(kind, 1)
        self._seen[kind] = t_ns
        new_episode = seen is None or t_ns - seen > EPISODE_GAP * self._interval_ns
        if not new_episode and last is not None and t_ns - last < factor * self._interval_ns:
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return
        more = self._suppressed.pop(kind, 0)
        self._last[kind] = t_ns
        self._factor[kind] = 1 if new_episode else min(2 * factor, MAX_BACKOFF)
        tail = f" ({more} more since the last warning)" if more else ""
        log.warning("%s: %s%s", self.when(t_ns), message, tail)

    def note(self, t_ns: int, message: str) -> None:
        """An event worth a line at info level (not a warning: nothing is wrong yet)."""
        log.info("%s: %s", self.when(t_ns), message)

    def when(self, t_ns: int) -> str:
        """``t_ns`` as the warnings give it: seconds into the run once ``origin_ns`` is set."""
        if self.origin_ns is None:
            return f"t={t_ns * 1e-9:.3f} s"
        return f"{(t_ns - self.origin_ns) * 1e-9:.3f} s into the run"


@dataclass
class _Gap:
    """An IMU gap ``[start_ns, end_ns]`` whose noise is added as the filter crosses it.

    The held specific force and rate are off by a constant over the gap (``gap_covariance``);
    added all at once at the gap's start, that covariance would be spent by the first updates
    inside the gap, before the error it stands for has grown. So it is spread over the gap as
    white noise of intensity ``σ² T`` (T the gap's length): at the gap's end the velocity and
    attitude variances equal ``gap_covariance``'s, the position's is 4/3 of it.
    """

    start_ns: int
    end_ns: int
    accel_std: float  # m/s²
    gyro_std: float  # rad/s
    applied_ns: int = -1  # gap time up to which the noise was added (-1: none yet)

    def take(self, t_ns: int) -> F64 | None:
        """Noise (9, 9) of ``[applied, min(t_ns, end)]``, None when nothing new is crossed."""
        a = max(self.applied_ns, self.start_ns)
        b = min(t_ns, self.end_ns)
        if b <= a:
            return None
        self.applied_ns = b
        T = (self.end_ns - self.start_ns) * 1e-9
        dt = (b - a) * 1e-9
        qa, qw = self.accel_std**2 * T, self.gyro_std**2 * T
        Q = np.zeros((9, 9))
        eye = np.eye(3)
        Q[0:3, 0:3] = qa * dt**3 / 3 * eye
        Q[0:3, 3:6] = Q[3:6, 0:3] = qa * dt**2 / 2 * eye
        Q[3:6, 3:6] = qa * dt * eye
        Q[6:9, 6:9] = qw * dt * eye
        return Q


class ImuFaults:
    """``ImuGuard`` on the incoming samples (sensor frame S) and the gaps waiting for the core."""

    def __init__(self, rig: Rig, options: FaultOptions, warn: RateLimitedLog,
                 rest: StaticTest | None = None) -> None:
        """``rest``: the test of a resting platform; a long gap after a rest is bridged by
        holding the rest (see :meth:`accept`)."""
        assert rig.imu is not None
        self._rest = rest
        self._options = options
        self._warn = warn
        self._densities = (rig.imu.accel_noise_density, rig.imu.gyro_noise_density)
        guard_options = ImuGuardOptions(gap_factor=options.imu_gap_factor,
                                        drop_frozen=options.imu_drop_frozen)  # fmt: skip
        self.guard = ImuGuard.from_calib(rig.imu, guard_options)
        # gaps not yet crossed in full by the filter, or crossed less than _AFTER_GAP_NS ago
        self._gaps: list[_Gap] = []
        # a long gap (start, end) whose first sample after it awaits its mean
        self._pending: tuple[int, int] | None = None
        # the sample before a possible spike, until the sample after it decides
        self._suspect_ns: int | None = None
        self.last_fault_ns: int | None = None  # the latest dropped sample or gap end

    def accept(self, t_ns: int, gyro_S: ArrayLike, accel_S: ArrayLike, history: ImuHistory,
               used_until_ns: int | None = None) -> bool:  # fmt: skip
        """Whether the sample at ``t_ns`` enters ``history`` (queues the gap it ends, if any).
        ``used_until_ns``: the estimator has processed up to this time (None: nothing yet); a
        spike the guard recognises only now is removed from ``history`` if it has not been
        used, i.e. if the estimator has not passed the sample before it."""
        verdict = self.guard.check(t_ns, gyro_S, accel_S)
        self._suspect_ns = None if verdict.kind == "drop" else self.guard.suspect_from_ns()
        n = verdict.retract_previous
        if n and history.n >= n + 1:
            spike_ns = int(history.t_ns[-n])
            before_ns = int(history.t_ns[-n - 1])
            why = verdict.reason if verdict.kind == "drop" else "spike"
            if used_until_ns is None or used_until_ns <= before_ns:
                for _ in range(n):
                    history.drop_last()
                history.mark_fault(before_ns, t_ns)
                self.last_fault_ns = spike_ns
                self._warn.warn(f"imu-{why}", spike_ns, f"IMU sample dropped ({why}, seen from "
                                "the sample after it), bridged by its neighbours")  # fmt: skip
            else:  # (a rail's first samples were named a spike: a review)
                self._warn.warn(f"imu-{why}-late", spike_ns, f"IMU sample found {why} after "
                                "the estimator had used it: kept")  # fmt: skip
        if verdict.kind in ("drop", "gap"):
            self.last_fault_ns = t_ns
            last = history.last_ns
            history.mark_fault(t_ns if last is None else last, t_ns)  # from the last kept one
        if verdict.kind == "drop":
            why = f"IMU sample dropped ({verdict.reason}), bridged by its neighbours"
            self._warn.warn(f"imu-{verdict.reason}", t_ns, why)
            return False
        if self._pending is not None and t_ns > self._pending[1] + _FIT_NS:
            # The first sample after a long gap becomes the mean of the samples that followed
            # it within _FIT_S (the Navigator holds the filter at the gap's start until then).
            start, end = self._pending
            self._pending = None
            k = int(np.searchsorted(history.t_ns, end))
            if history.replace_by_mean(k, end, end + _FIT_NS) and k >= 1:
                self._widen_for_change(start, end, history, k)
        if verdict.kind == "gap":
            start_ns = t_ns - round(verdict.gap_s * 1e9)
            motion = self._spread(start_ns, history)  # before the fit: from the raw samples
            sample_std = self._sample_std()
            n_mean = 1
            if verdict.gap_s >= _LONG_GAP_S and history.n:
                n_mean = max(1, history.replace_by_mean(history.n - 1, start_ns - _FIT_NS,
                                                        start_ns))  # fmt: skip
                if self._rest is not None and self._rest.at_rest(history, start_ns):
                    # At rest before the gap: the platform is taken to rest on until the gap's
                    # end (a copy of the rest's mean 1 ms before it), not to turn towards the
                    # motion after it from the gap's start. On EuRoC (rotors on, take-off
                    # inside a 5 s gap) the chord made 20 m of error, the hold 0.9.
                    held_raw = history.raw(history.n - 1)
                    history.append(t_ns - min(_HOLD_END_NS, t_ns - start_ns - 1), held_raw[0:3],
                                   held_raw[3:6])  # fmt: skip
                self._pending = (start_ns, t_ns)
            elif sample_std is not None:
                history.fit_last(_FIT_S, np.repeat(sample_std[::-1], 3))  # gyro, then accel
            self._gaps.append(_Gap(start_ns, t_ns,
                                   *self._bridge_noise(motion, sample_std, n_mean)))
            self._warn.warn("imu-gap", t_ns, f"IMU gap of {verdict.gap_s:.3f} s: covariance "
                            "inflated by the noise it skipped")  # fmt: skip
        return True

    def _widen_for_change(self, start_ns: int, end_ns: int, history: ImuHistory, k: int) -> None:
        """Widen the noise of the gap ``[start_ns, end_ns]`` by the change ``Δ`` between its two
        end means (the rows at ``start_ns`` and ``k`` of ``history``, sensor frame).

        Taken as a switch from one to the other at an unknown time, uniform over the gap: the
        chord between them is the mean of that motion, its integral's error has the standard
        deviation ``|Δ| T / √12``, a constant error of ``|Δ| / √12`` (per axis, RMS over the
        axes) in the model's terms. The same after a rest, where the bridge holds the first:
        counting the hold's mean offset ``Δ T / 2`` too (``|Δ| / √3``) made the sigma points so
        wide that the EuRoC gap at 2 s ended 1.57 m off instead of 1.01. The motion spread
        before the gap does not see a change that happened inside it (EuRoC: a take-off during
        a 5 s gap)."""
        t = history.t_ns
        k0 = int(np.searchsorted(t, start_ns))
        if k0 >= k or t[k0] != start_ns or t[k] < end_ns:
            return
        delta = history.raw(k) - history.raw(k0)
        for gap in self._gaps:
            if gap.start_ns == start_ns and gap.end_ns == end_ns:
                da = float(np.sqrt(np.mean(delta[3:6] ** 2) / 12.0))
                dg = float(np.sqrt(np.mean(delta[0:3] ** 2) / 12.0))
                gap.accel_std = math.hypot(gap.accel_std, da)
                gap.gyro_std = math.hypot(gap.gyro_std, dg)

    @property
    def hold_ns(self) -> int | None:
        """The time the filter must not propagate past yet (None: no limit): a long gap's start
        while its end awaits its window mean, and the sample before a possible spike until the
        next sample tells whether it was one."""
        holds = [h for h in (None if self._pending is None else self._pending[0],
                             self._suspect_ns) if h is not None]  # fmt: skip
        return min(holds) if holds else None

    def _sample_std(self) -> tuple[float, float] | None:
        """One sample's white noise (accel m/s², gyro rad/s) at the observed spacing (None
        before any spacing is known)."""
        dt_s = self.guard.median_spacing_s() or 0.0
        if dt_s <= 0:
            return None
        accel_d, gyro_d = self._densities
        return accel_d / math.sqrt(dt_s), gyro_d / math.sqrt(dt_s)

    @staticmethod
    def _bridge_noise(
        motion: tuple[float, float], sample_std: tuple[float, float] | None, n_mean: int = 1
    ) -> tuple[float, float]:
        """Per-axis std (m/s², rad/s) of the bridge's error over a gap: the motion spread
        before it (``_spread``) and the white noise of the bridge's two end samples
        (``sample_std``, accel and gyro), in quadrature.

        Each end sample's noise is held across the gap: their mean error integrates to
        ``T (n0 + n1) / 2``, a variance of ``(σ0² + σ1²) T² / 4``, i.e. ``σ² / 2`` in the
        model's ``σ² T²``. On a noisy IMU (the paper's: 0.12 rad/s and 0.7 m/s² per sample) this
        is most of a bridge's error, so the first end point is replaced by a line fitted through
        the last ``_FIT_S`` of samples, where they are a line plus white noise
        (``ImuHistory.fit_last``), which removes most of its noise. The model keeps the single
        sample's variance for it all the same: the margin covers the motion that one second
        before a gap underestimates (bench/faults.py seeds 0-23, ``3d`` after the 5 s gap: NEES
        9.76 so, 10.22 with the fitted point's ``(4n - 2) / (n (n + 1))`` of a sample's
        variance; the RMSE is the same either way).

        A long gap's ends are means of ``n_mean`` samples each (``ImuFaults.accept``): their
        white noise is ``σ² / n_mean``, so the term is ``σ² / (2 n_mean)`` (with one sample's
        variance the model was 13 times the bridge's real error on a resting IMU with the
        paper's noise, 2 s gap, ``tests/test_gap_noise.py``).
        """
        if sample_std is None:
            return motion
        k = 2.0 * n_mean
        return (math.sqrt(motion[0] ** 2 + sample_std[0] ** 2 / k),
                math.sqrt(motion[1] ** 2 + sample_std[1] ** 2 / k))  # fmt: skip

    def _spread(self, start_ns: int, history: ImuHistory) -> tuple[float, float]:
        """Per-axis std (m/s², rad/s) of the accelerometer and gyro signal in the
        ``gap_spread_s`` before ``start_ns``: the spread of its ``_BLOCK_S`` block means, so the
        samples' white noise (which averages out over a gap) does not count as motion; at
        least the white noise of one block mean."""
        t = history.t_ns
        sel = np.flatnonzero(t >= start_ns - int(self._options.gap_spread_s * 1e9))
        accel_std, gyro_std = (d / math.sqrt(_BLOCK_S) for d in self._densities)
        if sel.size >= 2:
            block = (t[sel] - t[sel[0]]) // int(_BLOCK_S * 1e9)
            _, first = np.unique(block, return_index=True)
            if first.size >= 2:
                n = np.diff([*first, sel.size])[:, None]
                a = np.add.reduceat(history.accel_B[sel], first) / n
                g = np.add.reduceat(history.gyro_B[sel], first) / n
                accel_std = max(accel_std, float(np.mean(np.std(a, axis=0))))
                gyro_std = max(gyro_std, float(np.mean(np.std(g, axis=0))))
        return accel_std, gyro_std

    def take_noise(self, t_ns: int) -> F64 | None:
        """Covariance (9, 9) of the gap time the filter crossed since the last call, up to
        ``t_ns`` (None: no gap crossed)."""
        total: F64 | None = None
        for gap in self._gaps:
            Q = gap.take(t_ns)
            if Q is not None:
                total = Q if total is None else total + Q
        self._gaps = [g for g in self._gaps if t_ns <= g.end_ns + _AFTER_GAP_NS]
        return total

    def bridging(self, t_ns: int) -> bool:
        """Whether ``t_ns`` lies in an IMU gap or less than ``_AFTER_GAP_NS`` after one: the
        prediction there rests on the bridge and its wide noise (the Core then linearises the
        vision update again, ``faults.gap_vision_iterations``)."""
        return any(g.start_ns < t_ns <= g.end_ns + _AFTER_GAP_NS for g in self._gaps)

    def summary(self) -> dict[str, object]:
        return self.guard.summary()


class Recovery:
    """``ConsistencyMonitor`` fed by every gated update; applies its actions to ``ukf``."""

    def __init__(self, options: FaultOptions, warn: RateLimitedLog, gps_used: bool = True,
                 bias_random_walk_var: Callable[[], F64] | None = None,
                 heading_witness: bool = False,
                 clone_times: Callable[[], tuple[int, ...]] | None = None) -> None:  # fmt: skip
        """``gps_used``: the run fuses GPS (else vision alone may call for an inflation).
        ``bias_random_walk_var() -> (6,)``: the filter's bias random-walk variances per second
        (gyro then accelerometer), for recalling the biases after a bias alarm
        (``navigation.bias_recall``); None: zero. ``heading_witness``: the run fuses another
        sensor that holds the heading between magnetometer samples (vision), so a leaning
        magnetometer's samples are taken back (``faults.lean_unfuse``); ``clone_times()``:
        the times of the state's pose clones (``navigation.unfuse``)."""
        self.monitor = ConsistencyMonitor(ConsistencyOptions(
            inflate_factor=options.inflate_factor, anchor_in_use=gps_used,
            bias_window=options.bias_test_window,
            bias_probability=options.bias_test_probability,
            bias_rate_probability=options.bias_test_rate_probability,
            bias_sensors=("gps", *ConsistencyOptions.standalone_sensors)
            if self._vision_lean(options, gps_used) else ("gps",),
            vision_bias_window=options.bias_test_vision_window,
            vision_bias_probability=options.bias_test_vision_probability,
            jump_hold_s=options.gps_jump_hold_s,
            jump_erratic_probability=options.gps_scatter_probability,
            rate_drop=options.gps_velocity_drop_s is not None,
            lean_probability=options.lean_test_probability))  # fmt: skip
        self._options = options
        self._warn = warn
        self._bias_rw = bias_random_walk_var
        self._alarm: BiasAlarm | None = None  # a bias alarm waiting for its confirmation
        self.bias_confirmed = 0
        self.bias_restored = 0
        self.reset_pending = False
        # (sensor, "rate" | "all") -> t_ns until which that part of it is not fused
        self._off_until_ns: dict[tuple[str, str], int] = {}
        o = self.monitor.options
        self.shares = (LeanShares(o.lean_sensors, o.lean_window)
                       if options.lean_unfuse and heading_witness and o.lean_probability is not None
                       else None)  # fmt: skip
        self.unfused = 0  # samples of a leaning sensor taken back (``navigation.unfuse``)
        self._clone_times = clone_times or tuple
        # (t_ns, position σ m, sensors refusing) each time the filter was found lost
        self.lost: list[tuple[int, float, tuple[str, ...]]] = []
        self._lost_now = False

    @staticmethod
    def _vision_lean(options: FaultOptions, gps_used: bool) -> bool:
        return (options.bias_test_vision_probability is not None
                and options.bias_test_probability is not None
                and (gps_used or options.bias_test_vision_gps_denied))  # fmt: skip

    def tests_vision(self, method: str) -> bool:
        """Whether the updates of the vision ``method`` feed the bias test (their corrections
        whitened, :func:`whitened_correction`)."""
        return method in self.monitor.options.bias_sensors

    def held(self, sensor: str, t_ns: int) -> bool:
        """Whether ``sensor`` is not fused at ``t_ns``: its innovations leaned
        (``ConsistencyMonitor.leaning``) less than ``FaultOptions.lean_hold_s`` ago."""
        return t_ns < self._off_until_ns.get((sensor, "all"), -1)

    def rate_off(self, sensor: str, t_ns: int) -> bool:
        """Whether ``sensor`` (GPS) is fused without its rate channel (velocity) at ``t_ns``:
        the monitor found it alone disagreeing (``drop_rate``) less than
        ``FaultOptions.gps_velocity_drop_s`` ago."""
        return t_ns < self._off_until_ns.get((sensor, "rate"), -1)

    def _switch_off(self, action: RecoveryAction, part: str, hold_s: float, t_ns: int) -> None:
        """Stop fusing ``part`` of ``action``'s sensors for ``hold_s`` from ``t_ns``, warned."""
        for name in action.sensors:
            self._off_until_ns[(name, part)] = int(t_ns) + round(hold_s * 1e9)
        self._warn.warn(f"recovery-{action.kind}", t_ns, f"{action.reason} ({hold_s:g} s)")

    @property
    def bias_pending(self) -> bool:
        """A bias alarm's step is in the state, neither confirmed nor undone."""
        return self._alarm is not None

    def observe(self, stats: UpdateStats, key: str, t_ns: int) -> None:
        if math.isfinite(stats.gate):  # ungated updates say nothing about the filter's health
            self.monitor.observe(key, stats.accepted, stats.nis, stats.dof, t_ns, stats.gate,
                                 stats.whitened, stats.residual,
                                 stats.innovation_cov)  # fmt: skip
            if self.shares is not None:
                self.shares.observe(stats, self._clone_times())

    @property
    def watched(self) -> str | None:
        """The sensor whose update shares the filter is asked for (``contribution_of``)."""
        return self.shares.sensors[0] if self.shares is not None and self.shares.sensors else None

    def check(self, ukf: UKF, t_ns: int) -> None:
        """Ask the monitor after a group of updates and apply its action."""
        if self._alarm is not None:
            self._confirm_bias(ukf, t_ns)
        held = self.monitor.leaning(t_ns)
        if held is not None:
            self._switch_off(held, "all", self._options.lean_hold_s, t_ns)
            if self.shares is not None:
                for name in held.sensors:
                    taken = self.shares.take(name)
                    unfuse(ukf, taken, self._clone_times())
                    self.unfused += len(taken)
        position_std_m = math.sqrt(float(np.trace(ukf.P[DP, DP])) / 3.0)
        self._check_lost(t_ns, position_std_m)
        action = self.monitor.should_recover(t_ns, position_std_m)
        if action is None:
            self._check_bias(ukf, t_ns)
            return
        if self._alarm is not None:  # the filter is lost: what it knew before is no anchor
            self._alarm = None
            drop_step(ukf)
        if action.kind == "distrust":
            self._warn.warn("recovery-distrust", t_ns, action.reason)
            return
        if action.kind == "drop_rate":
            hold_s = self._options.gps_velocity_drop_s
            assert hold_s is not None  # the monitor answers drop_rate only with a hold
            self._switch_off(action, "rate", hold_s, t_ns)
            return
        self._warn.warn(f"recovery-{action.kind}", t_ns,
                        f"filter inconsistent ({action.reason}): {action.kind}")  # fmt: skip
        if action.kind == "inflate":
            inflate(ukf, action)
        else:
            self.reset_pending = True

    def _check_lost(self, t_ns: int, position_std_m: float) -> None:
        """Warn, once per episode, when sensors refuse a filter whose position is already
        uncertain beyond the monitor's ``max_position_std_m``: no recovery applies there (an
        inflation would not widen it usefully), so the estimate is dead reckoning until a
        sensor agrees again. Before this line a run that lost its filter (EuRoC every 15th
        frame with ``--rotation imu``: 1110 m) said only that vision was missing and the filter
        inconsistent, and exited 0 (a user's probe)."""
        limit = self.monitor.options.max_position_std_m
        if position_std_m < limit:
            self._lost_now = False
            return
        refusing = self.monitor.rejecting(t_ns)
        if self._lost_now or not refusing:
            return
        self._lost_now = True
        self.lost.append((int(t_ns), position_std_m, refusing))
        verb = "refuse" if len(refusing) > 1 else "refuses"
        self._warn.warn("recovery-lost", t_ns, f"the filter is lost: its position is uncertain "
                        f"to {position_std_m:.3g} m (beyond {limit:g} m, where no recovery "
                        f"applies) and {', '.join(refusing)} {verb} it; the estimate is dead "
                        "reckoning until a sensor agrees again")  # fmt: skip

    def _check_bias(self, ukf: UKF, t_ns: int) -> None:
        """The monitor's bias test (``ConsistencyMonitor.biased``): widen the IMU biases (a
        state without biases, the paper's, takes no test)."""
        if not _has_biases(ukf):
            return
        action = self.monitor.biased(t_ns)
        if action is None:
            return
        o = self._options
        message = f"{action.reason} The IMU biases are widened"
        if o.bias_confirm_s is None:
            self._warn.warn("recovery-bias", t_ns, message)
            widen_biases(ukf, o.bias_widen_factor, o.bias_max_gyro_std, o.bias_max_accel_std,
                         0.5 * action.window_s)  # fmt: skip
            return
        # A pending alarm is said at info level: the test fires a few times on a clean run (its
        # 0.975 quantile, one test per fix; the demo: three per method) and a false alarm is
        # undone; only a confirmed step is warned (``_confirm_bias``).
        self._warn.note(t_ns, message + " until confirmed")
        if self._alarm is None:
            self._alarm = BiasAlarm.before_widening(ukf, t_ns, o.bias_confirm_s)
        else:  # a second alarm before the first is confirmed: the older biases stay
            self._alarm.confirm_ns = int(t_ns + o.bias_confirm_s * 1e9)
        inject_step(ukf, step_variances(ukf, o.bias_widen_factor, o.bias_max_gyro_std,
                                        o.bias_max_accel_std, 0.5 * action.window_s))

    def _confirm_bias(self, ukf: UKF, t_ns: int) -> None:
        """The pending bias alarm (``navigation.bias_recall``): confirmed once the biases have
        left those from before it; recalled when the test's sensors fall silent (GPS, and the
        vision updates where they feed the test) or at its deadline."""
        alarm = self._alarm
        assert alarm is not None
        rw = np.zeros(6) if self._bias_rw is None else self._bias_rw()
        o = self._options
        nis = bias_change_nis(ukf, alarm, t_ns, rw)
        dt_s = (t_ns - alarm.t_ns) * 1e-9
        gate = chi2_gate(o.bias_confirm_probability, 6)
        if nis > gate:
            self._alarm = None
            drop_step(ukf)
            self.bias_confirmed += 1
            self._warn.warn("recovery-bias-confirmed", t_ns, "an IMU bias step is confirmed: "
                            f"the biases learnt since the alarm of {dt_s:.1f} s ago left those "
                            f"from before it (chi-square {nis:.3g} > {gate:.3g}, 6 dof); the "
                            "widened biases stay")  # fmt: skip
            return
        last = self.monitor.last_accepted_ns(self.monitor.options.bias_sensors)
        silent = last is None or t_ns - last > _ANCHOR_SILENT_NS
        if t_ns < alarm.confirm_ns and not silent:
            return
        self._alarm = None
        undo_step(ukf)  # decided above: fused ungated
        self.bias_restored += 1
        why = "the GPS fell silent" if silent and t_ns < alarm.confirm_ns else "no step"
        self._warn.note(t_ns, f"the bias alarm of {dt_s:.1f} s ago is not confirmed ({why}; "
                        f"chi-square {nis:.3g} <= {gate:.3g}, 6 dof): the biases from before it "
                        "are restored")  # fmt: skip

    def state_replaced(self, ukf: UKF) -> None:
        """The filter's state is about to be replaced whole (a bank of headings merged,
        ``navigation.yaw_bank``): a pending bias alarm's step is dropped (the state it was
        appended to goes) and the bias test's window forgotten (innovations of the old
        state)."""
        if self._alarm is not None:
            self._alarm = None
            drop_step(ukf)
        self.monitor.clear_bias_evidence()

    def reset_from_gps(self, ukf: UKF, cal: GpsCalib, p_W_G: F64, v_W_G: F64 | None) -> None:
        """Position (and velocity, when the fix has one) from the GPS fix; their covariance
        from its noise, uncorrelated with the rest of the state.

        Pose clones (``models.clones``) move with the position: the filter had lost the absolute
        position, not the motion since each clone, so each clone is shifted by the same amount
        and its position error set equal to the new one (``shift_clones``). Otherwise the next
        vision update would see the reset's jump as motion between two frames.
        """
        x = ukf.x.copy()
        p_old = x[P].copy()
        x[P] = 0.0
        x[P] = p_W_G - gps_position(x[None], cal.p_B_G)[0]
        idx = [*range(DP.start, DP.stop)]
        var = [cal.position_noise_std**2] * 3
        if v_W_G is not None:
            x[V] = 0.0
            x[V] = v_W_G - gps_velocity(x[None], cal.p_B_G)[0]
            idx += [*range(DV.start, DV.stop)]
            var += [cal.velocity_noise_std**2] * 3
        Pm = ukf.P.copy()
        Pm[idx, :] = 0.0
        Pm[:, idx] = 0.0
        Pm[idx, idx] = var
        if isinstance(ukf.manifold, CloneManifold) and ukf.manifold.n_clones:
            x, Pm = shift_clones(x, Pm, ukf.manifold, x[P] - p_old)
        ukf.x, ukf.P = x, Pm
        self.reset_pending = False

    def summary(self) -> dict[str, object]:
        out = self.monitor.summary()
        out["bias_confirmed"] = self.bias_confirmed
        out["bias_restored"] = self.bias_restored
        out["lean_unfuse"] = self.shares is not None  # armed: a lean's samples are taken back
        out["lean_unfused"] = self.unfused
        out["lost"] = [{"t_ns": t, "position_std_m": round(std, 3), "refusing": list(names)}
                       for t, std, names in self.lost]  # fmt: skip
        return out


def shift_clones(x: F64, P_: F64, manifold: CloneManifold, dp_W: F64) -> tuple[F64, F64]:
    """Clone positions moved by ``dp_W`` (3, m), their position errors made equal to the
    current position's (rows, columns and the block among them copied from ``δp``, plus the
    clone jitter): ``x`` (nx,), ``P`` (ndx, ndx) -> new copies. Clone attitudes are kept."""
    x, P_ = x.copy(), P_.copy()
    dp = np.arange(P_.shape[0])[DP]
    rows = [manifold.tangent(i).start + np.arange(3) for i in range(manifold.n_clones)]
    for i, r in enumerate(rows):
        x[manifold.columns(i)[0]] += dp_W
        P_[r, :] = P_[dp, :]
        P_[:, r] = P_[:, dp]
    for r in rows:  # with the copies above, every pair of the group now holds P[δp, δp]
        P_[r, r] += CloneManifold.clone_jitter(P_[r, r])
    return x, 0.5 * (P_ + P_.T)


def _has_biases(ukf: UKF) -> bool:
    """Whether the filter's navigation block has the biased layout (gyro and accelerometer
    biases, ``DBG``/``DBA``), clones and calibration aside."""
    nav_ndx = ukf.manifold.nav.ndx if isinstance(ukf.manifold, CloneManifold) else ukf.P.shape[0]
    return nav_ndx >= DBA.stop


def inflate(ukf: UKF, action: RecoveryAction) -> None:
    """``scale_motion_covariance(ukf, action.inflate_factor)``."""
    scale_motion_covariance(ukf, action.inflate_factor)


def scale_motion_covariance(ukf: UKF, factor: float) -> None:
    """P ← D P D with D = sqrt(factor) on δp, δv, δθ, on the IMU biases (biased model) and on
    every pose clone's (δp, δθ), 1 elsewhere.

    The biases: a filter lost after a bias step (a knocked or overheated IMU) would otherwise
    be sure of the old bias, drift off again after each recovery and lock GPS out for good
    (bench: a 0.5 m/s² accelerometer step). The clones are past poses of the same lost filter:
    left as they were, their small covariance would let the next vision update (relative
    motion to a clone) pin the inflated position back onto the clone's wrong one. Scaling them
    with the current pose keeps every correlation.
    """
    d = np.ones(ukf.P.shape[0])
    root = math.sqrt(factor)
    d[NAV9] = root
    assert DTH.stop == NAV9.stop
    if isinstance(ukf.manifold, CloneManifold):
        for i in range(ukf.manifold.n_clones):
            d[ukf.manifold.tangent(i)] = root
    if _has_biases(ukf):
        d[DBG] = root
        d[DBA] = root
    ukf.P = ukf.P * np.outer(d, d)


def step_variances(ukf: UKF, factor: float, max_gyro_std: float, max_accel_std: float,
                   elapsed_s: float = 0.0) -> F64:  # fmt: skip
    """The step a bias alarm injects (``navigation.bias_recall.inject_step``), variances (12,):
    gyro bias, accelerometer bias, attitude, velocity. Each bias standard deviation grows by
    ``sqrt(factor)``, capped at ``max_gyro_std`` (rad/s) or ``max_accel_std`` (m/s²) and never
    shrinking: the added standard deviations σ_g, σ_a. Attitude and velocity get the spread such
    a step would have caused over τ = ``elapsed_s`` (s), (σ_g τ)² and (σ_a τ)²: the state already
    carries the step's effect since it happened, which the covariance did not. Not
    (σ_a τ² / 2)² on δp: GPS measures the position itself, and on the fault bench that term
    cost a clean run with a false alarm 22 % of its RMSE for no gain after a step."""
    diag = np.diag(ukf.P)
    added = []
    for block, cap in ((DBG, max_gyro_std), (DBA, max_accel_std)):
        std = np.sqrt(np.maximum(diag[block], 1e-300))
        new = np.maximum(np.minimum(std * math.sqrt(factor), cap), std)
        added.append(new * new - std * std)
    tau = float(elapsed_s)
    return np.concatenate([added[0], added[1], added[0] * tau * tau, added[1] * tau * tau])


def widen_biases(ukf: UKF, factor: float, max_gyro_std: float, max_accel_std: float,
                 elapsed_s: float = 0.0) -> None:  # fmt: skip
    """After a bias alarm with no confirmation (``faults.bias_confirm_s`` None): P ← D P D
    with D = sqrt(factor) on the IMU biases' tangent entries (biased layout), each capped as
    in :func:`step_variances` (correlations kept); 1 elsewhere. Then the spread of
    :func:`step_variances` on attitude and velocity, uncorrelated."""
    if not _has_biases(ukf):
        return
    var = step_variances(ukf, factor, max_gyro_std, max_accel_std, elapsed_s)
    i = np.arange(ukf.P.shape[0])
    bias_rows = np.r_[i[DBG], i[DBA]]
    d = np.ones(i.size)
    d[bias_rows] = np.sqrt(1.0 + var[:6] / np.maximum(np.diag(ukf.P)[bias_rows], 1e-300))
    P_ = ukf.P * np.outer(d, d)
    P_[i[DTH], i[DTH]] += var[6:9]
    P_[i[DV], i[DV]] += var[9:12]
    ukf.P = P_


def add_gap_covariance(ukf: UKF, Q9: F64) -> None:
    """Add a gap's covariance (9, 9) to the p/v/θ block of ``ukf.P``."""
    Pm = ukf.P.copy()
    Pm[NAV9, NAV9] += Q9
    ukf.P = Pm


def whitened_correction(ukf: UKF, x_prior: F64, P_rows_prior: F64,
                        rows: NDArray[np.int64]) -> F64 | None:  # fmt: skip
    """An update's correction of the tangent ``rows`` of ``ukf``'s state, whitened by the
    covariance the update removed from them: ``w = L^-1 (x ⊖ x_prior)[rows]`` with ``L L^T =
    P_prior - P`` over the rows (``P_rows_prior``: the prior's block over ``rows`` only). For a
    consistent linear filter the correction ``K r`` has exactly that covariance, so ``w`` is
    white and unit, and a run of them that lean one way is the same bias test as the GPS
    innovations' (``ConsistencyMonitor.biased``). None when the state changed size or the
    update removed too little to whiten (not positive definite)."""
    if ukf.x.shape != x_prior.shape:
        return None
    d = ukf.manifold.local(ukf.x[None], x_prior)[0][rows]
    C = P_rows_prior - ukf.P[np.ix_(rows, rows)]
    try:
        L = np.linalg.cholesky(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        return None
    return np.asarray(scipy.linalg.solve_triangular(L, d, lower=True))
