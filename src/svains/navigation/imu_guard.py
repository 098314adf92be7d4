"""Per-sample IMU fault filter: saturation, spikes, dead (all-zero or frozen) output and gaps.

``ImuGuard.check(t_ns, gyro_B, accel_B)`` returns a :class:`Verdict` for each sample, in time
order. A dropped sample is to be skipped by the integrator, which then bridges from the last
accepted sample to the next one (the rate and force held over the bridge). A ``gap`` verdict
accepts its sample and reports how long the integrator had no data before it, so the core can
add the process noise of that time to the covariance. Counters go to ``report.json``
(:meth:`ImuGuard.summary`). Pure numpy: no data-set access.

Thresholds (``ImuGuardOptions``), each from a model or a measurement:

- **saturation**: an axis at or beyond ``saturation_fraction`` of the full scale (the IMU
  ``sensor.yaml``'s ``gyroscope_range``/``accelerometer_range`` when given, else 16 g and
  2000 deg/s, common MEMS full scales) is a clipped reading.
- **spike**: the jump from the last accepted sample beyond what motion and noise allow,
  ``floor + rate_bound * dt + spike_sigma * sqrt(6) * sigma`` (``sqrt(6)``: the norm of the
  difference of two independent 3-axis samples, ``sigma`` the per-sample noise std from the
  noise density at the observed spacing). The floors are measured: real EuRoC V1_01 (an
  ADIS16448 on a vibrating MAV) jumps up to 11.9 m/s² and 0.31 rad/s between 5 ms samples,
  KITTI raw's OXTS up to 2.1 m/s² and 0.14 rad/s; the floors, 40 m/s² and 5 rad/s, leave a
  margin of 3x and more, and a spike of 100 m/s² or 10 rad/s is still caught.
- **dead output**: all six channels exactly zero (a level IMU reads gravity, noise never gives
  six exact zeros), or **frozen**: all six exactly equal to the last accepted sample's (a hung
  sensor or a driver repeating its last message with new stamps; noise never repeats six
  values: none of EuRoC V1_01's 29,120 samples nor KITTI raw's 597 does), or one triad (the
  gyro's or the accelerometer's three axes) equal to the last accepted one's in
  ``frozen_triad_run`` samples in a row after it had changed in each of the ``live_run``
  samples before (one sensor of the two hung: a gyro held 3 s on the real EuRoC IMU took ``3d``
  173 m off; a live, noisy triad repeats its three values about never, and the first repeats,
  still the true values, are kept; a triad that was not changing, e.g. a noise-free simulated
  accelerometer, or one held at exact zeros, a deadband, is not judged). Off with
  ``drop_frozen=False`` (``faults.imu_drop_frozen``) for a coarsely quantised IMU at rest.
- **railed axis**: one axis that changed at each of its last ``live_run`` samples holding
  exactly the value of the sample before, beyond ``rail_factor`` times every value it showed
  while changing and beyond a floor (``rail_floor_accel`` 1.9 g: a ±2 g sensor's rail,
  ``rail_floor_gyro`` 1 rad/s), or exactly on a rail found so before: a reading clipped at a
  full scale the calibration does not give (a user's probe: an accelerometer pinned at 10 g, or at
  50 m/s² with the gyro at 5 rad/s, for 0.5 s took KITTI raw ``3d`` 15-277 m off). The first
  sample of the rail is retracted with the second (``retract_previous``); its later samples
  are dropped while the axis keeps its value. A live axis repeats a new extreme about never. A
  rail reached smoothly is not caught here (a flat stretch of motion on a quiet axis holds its
  value as exactly); recorded files are checked whole on load (``datasets.validate``).
- **gap**: accepted samples further apart than ``gap_factor`` times the median observed spacing
  (the rate in ``sensor.yaml`` is nominal only: KITTI raw's OXTS, nominally 100 Hz, has a median
  spacing of 40 ms and gaps up to 250 ms, which must not be flagged sample after sample).
- **re-anchoring**: after ``max_consecutive_drops`` spike drops in a row the new level is taken
  as real (a hard landing is not a spike), so a step change cannot lock the IMU out.
- **a spike found by the sample after it**: after a longer spacing the motion allowance lets a
  spike through (KITTI raw's OXTS, 70 ms: 40 + 70 m/s²), and the good sample after it could be
  the one dropped. When the last accepted sample is beyond floor and noise (no motion
  allowance) from both the one before it and the new one, and those two agree, it was the
  spike (or the last two, ``MAX_SPIKE_RUN``): the verdict asks to ``retract_previous`` them
  (the caller removes them if the estimator has not used them yet) and the sample is judged
  against the one before. (KITTI raw with one 100 m/s² sample 70 ms after the one before:
  `ins` ended 76 m off, GPS blamed and shut out.)
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.sensors.types import ImuCalib

Vec3 = tuple[float, ...]
G0 = 9.80665  # m/s², standard gravity (full scales are quoted in g)

VerdictKind = Literal["accept", "drop", "gap"]
DropReason = Literal["nonfinite", "zeros", "frozen", "saturated", "spike"]
DROP_REASONS: tuple[DropReason, ...] = ("nonfinite", "zeros", "frozen", "saturated", "spike")
_MEDIAN_EVERY = 16  # accepted spacings between two recomputations of the running median
FIRST_GAP_S = 0.5  # s: the stream's first spacing is a gap only when longer (a long gap's bridge)
MAX_SPIKE_RUN = 2  # samples a spike found by the sample after it may last


@dataclass(frozen=True)
class ImuGuardOptions:
    """Thresholds of :class:`ImuGuard` (see the module docstring for where each comes from)."""

    gyro_range: float = math.radians(2000.0)  # rad/s, full scale when the calibration has none
    accel_range: float = 16.0 * G0  # m/s², full scale when the calibration has none
    saturation_fraction: float = 0.98  # of the full scale: at or beyond it a reading is clipped
    spike_sigma: float = 6.0  # noise standard deviations allowed in a jump
    accel_spike_floor: float = 40.0  # m/s², measured jumps of real IMUs stay below 12
    gyro_spike_floor: float = 5.0  # rad/s, measured jumps of real IMUs stay below 0.32
    jerk_bound: float = 1000.0  # m/s³, motion allowance per second between samples
    angular_accel_bound: float = 200.0  # rad/s², same for the gyro
    gap_factor: float = 10.0  # a spacing above this many median spacings is a gap
    spacing_window: int = 64  # accepted spacings in the running median
    max_consecutive_drops: int = 5  # spike drops in a row before the new level is accepted
    drop_frozen: bool = True  # drop a sample equal on all six channels to the last accepted
    frozen_triad_run: int = 5  # one triad equal to the last accepted this many times: frozen
    live_run: int = 20  # ... if it had changed at each of this many samples before
    rail_factor: float = 1.5  # an axis held beyond this many times its live extremes: railed
    rail_floor_accel: float = 1.9 * 9.80665  # m/s², ...and beyond this (a ±2 g sensor's rail)
    rail_floor_gyro: float = 1.0  # rad/s, ...and beyond this


@dataclass(frozen=True)
class Verdict:
    """What to do with one sample: ``accept`` it, ``drop`` it (``reason``), or accept it after a
    ``gap`` of ``gap_s`` seconds without accepted data."""

    kind: VerdictKind
    reason: DropReason | None = None
    gap_s: float = 0.0
    retract_previous: int = 0  # the last accepted samples (this many) were a spike: remove them

    @property
    def accepted(self) -> bool:
        return self.kind != "drop"


@dataclass
class _Counters:
    accepted: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))
    gaps: int = 0
    gap_total_s: float = 0.0
    longest_gap_s: float = 0.0
    reanchored: int = 0


class ImuGuard:
    """Stateful per-sample check of an IMU stream (samples in increasing time).

    ``gyro_noise_density`` (rad/s/√Hz) and ``accel_noise_density`` (m/s²/√Hz) set the noise part
    of the spike bound; ``nominal_rate_hz`` seeds the spacing until samples are seen; ``gyro_range``
    (rad/s) and ``accel_range`` (m/s²) are the full scales (None: ``options``' defaults).
    """

    def __init__(
        self,
        gyro_noise_density: float,
        accel_noise_density: float,
        nominal_rate_hz: float | None = None,
        gyro_range: float | None = None,
        accel_range: float | None = None,
        options: ImuGuardOptions | None = None,
    ) -> None:
        self.options = options or ImuGuardOptions()
        o = self.options
        self._gyro_density = float(gyro_noise_density)
        self._accel_density = float(accel_noise_density)
        self._gyro_sat = o.saturation_fraction * (gyro_range or o.gyro_range)
        self._accel_sat = o.saturation_fraction * (accel_range or o.accel_range)
        self._nominal_dt_s = 1.0 / nominal_rate_hz if nominal_rate_hz else None
        self._spacings: deque[float] = deque(maxlen=o.spacing_window)
        self._median_s: float | None = None  # cached median of ``_spacings``
        self._since_median = 0
        # the last accepted samples (t_ns, gyro, accel), newest last: a spike of up to
        # MAX_SPIKE_RUN and the one before it
        self._recent: deque[tuple[int, Vec3, Vec3]] = deque(maxlen=MAX_SPIKE_RUN + 1)
        # the lengths n of the runs of last accepted samples that all jumped beyond floor and
        # noise from the one before them (a spike, if the next sample goes back); kept up to
        # date by ``_accept`` for the next check and for ``suspect_from_ns``
        self._suspect_runs: list[int] = []
        self._retract = 0  # the sample being judged shows the last this many were a spike
        self._streak = 0
        self._triad_repeats = [0, 0]  # samples in a row whose gyro / accel equals the last kept
        self._triad_live = [0, 0]  # accepted samples in a row whose gyro / accel changed
        self._triad_armed = [False, False]  # the repeat run began on a live triad
        # railed axes: the largest |value| each axis showed while changing, the previous
        # sample's values (any verdict), each axis's railed value while it holds it
        self._live_max = [0.0] * 6
        self._axis_live = [0] * 6  # accepted samples in a row that changed each axis
        self._prev_seen: Vec3 | None = None
        self._rail: list[float | None] = [None] * 6
        self._rail_retract = 0
        # each axis's rail once found: a later reading exactly on it is clipped too (a sensor
        # vibrating at its rail leaves it and comes back)
        self._rail_seen: list[float | None] = [None] * 6
        self.counts = _Counters()

    @classmethod
    def from_calib(cls, calib: ImuCalib, options: ImuGuardOptions | None = None) -> ImuGuard:
        """A guard for the IMU of ``calib`` (noise densities, nominal rate, full scales)."""
        return cls(calib.gyro_noise_density, calib.accel_noise_density, calib.rate_hz,
                   calib.gyro_range, calib.accel_range, options)  # fmt: skip

    def median_spacing_s(self) -> float | None:
        """Median spacing of the accepted samples so far (the nominal period before any)."""
        if self._median_s is None and self._spacings:
            self._median_s = float(np.median(self._spacings))
        return self._median_s if self._spacings else self._nominal_dt_s

    def check(self, t_ns: int, gyro_B: ArrayLike, accel_B: ArrayLike) -> Verdict:
        """Verdict on the sample at ``t_ns``: ``gyro_B`` (3,) rad/s, ``accel_B`` (3,) m/s²."""
        # Plain floats: this runs once per IMU sample, where numpy's per-call cost dominates.
        g, a = _floats(gyro_B), _floats(accel_B)
        reason = self._fault(int(t_ns), g, a)
        self._prev_seen = g + a  # whatever the verdict (``_railed``)
        if reason is not None:
            self.counts.dropped[reason] += 1
            retract, self._rail_retract = self._rail_retract, 0
            if retract:  # the rail's first sample, accepted before the second showed it
                self._forget_last(retract, reason)
                self._suspect_runs = self._runs_of_suspects()
            return Verdict("drop", reason, retract_previous=retract)
        return self._accept(int(t_ns), g, a)

    def _forget_last(self, n: int, reason: DropReason) -> None:
        """The last ``n`` accepted samples counted dropped for ``reason`` instead."""
        self.counts.accepted -= n
        self.counts.dropped[reason] += n
        for _ in range(n):
            self._recent.pop()

    def _railed(self, values: Vec3) -> bool:
        """Whether an axis of ``values`` holds a railed value (see the module) against the
        previous sample's; keeps each axis's rail, and asks to retract the rail's first sample
        when it was the last accepted one."""
        o = self.options
        prev = self._prev_seen
        railed = False
        for i, v in enumerate(values):
            floor = o.rail_floor_gyro if i < 3 else o.rail_floor_accel
            # an axis that changed at each of its last ``live_run`` samples (a sample-and-hold
            # sensor repeating each value, or a noise-free simulated one, is not judged). Only
            # a jump far beyond every live value is a rail: one reached smoothly is not told
            # from a flat stretch of motion on a quiet axis (a drone yawing at 250 deg/s behind
            # a low-pass, a 2 g banked turn: thousands of samples dropped, two reviews).
            held = (v != 0.0 and prev is not None and v == prev[i]
                    and self._axis_live[i] >= o.live_run
                    and abs(v) >= max(floor, o.rail_factor * self._live_max[i]))  # fmt: skip
            if v == self._rail_seen[i]:
                self._rail[i] = v  # back on a rail found before: dropped as it comes
                railed = True
                continue
            if held:
                self._rail_seen[i] = v
            if held and self._rail[i] is None:
                last = self._last
                if last is not None and (last[1] + last[2])[i] == v and self._retract == 0:
                    self._rail_retract = 1  # the rail's first sample, accepted before
            self._rail[i] = v if held or self._rail[i] == v else None
            railed |= self._rail[i] is not None
        return railed

    def _fault(self, t_ns: int, g: Vec3, a: Vec3) -> DropReason | None:
        values = g + a
        if not all(map(math.isfinite, values)):
            return "nonfinite"
        if not any(values):
            return "zeros"
        last = self._last
        if self.options.drop_frozen and last is not None:
            if values == last[1] + last[2]:
                return "frozen"
            run, armed = self._triad_repeats, self._triad_armed
            # A triad held at exact zeros is a deadband (a yaw-rate sensor not turning), not a
            # hang: only a held non-zero triad is judged (a user's probe: a deadbanded gyro had
            # a third of its samples dropped with the live accelerometer, ins 33 m off).
            for i, same in enumerate((g == last[1] and any(g), a == last[2] and any(a))):
                if not same:
                    run[i] = 0
                    continue
                if run[i] == 0:
                    armed[i] = self._triad_live[i] >= self.options.live_run
                run[i] += 1
                if armed[i] and run[i] >= self.options.frozen_triad_run:
                    return "frozen"
        if self._railed(values) or (max(map(abs, g)) >= self._gyro_sat
                                    or max(map(abs, a)) >= self._accel_sat):  # fmt: skip
            return "saturated"
        run = self._spike_run_before(t_ns, g, a)
        if run:
            self._retract = run  # judged from the sample before the spike, which it agrees with
            return None
        if last is not None and self._is_spike(t_ns, g, a, last):
            self._streak += 1
            if self._streak <= self.options.max_consecutive_drops:
                return "spike"
            self.counts.reanchored += 1  # a persistent new level is motion, not a spike
        return None

    def _is_spike(
        self, t_ns: int, g: Vec3, a: Vec3, ref: tuple[int, Vec3, Vec3], motion: bool = True
    ) -> bool:
        """Whether (g, a) at ``t_ns`` jumped from the sample ``ref`` beyond the bound (without
        the motion allowance when not ``motion``)."""
        o = self.options
        t0, g0, a0 = ref
        dt = max((t_ns - t0) * 1e-9, 0.0) if motion else 0.0
        spacing = self.median_spacing_s() or dt or 1.0
        # per-sample noise std at the observed spacing: density / sqrt(spacing)
        k = o.spike_sigma * math.sqrt(6.0 / spacing)
        accel_bound = o.accel_spike_floor + o.jerk_bound * dt + k * self._accel_density
        gyro_bound = o.gyro_spike_floor + o.angular_accel_bound * dt + k * self._gyro_density
        jump_a = math.dist(a, a0)
        return jump_a > accel_bound or math.dist(g, g0) > gyro_bound

    @property
    def _last(self) -> tuple[int, Vec3, Vec3] | None:
        """The last accepted sample (t_ns, gyro, accel), None before any."""
        return self._recent[-1] if self._recent else None

    def _runs_of_suspects(self) -> list[int]:
        """The run lengths n (ascending, up to ``MAX_SPIKE_RUN``) whose last n accepted samples
        all jumped beyond floor and noise alone from the one before them."""
        r = self._recent
        return [n for n in range(1, min(MAX_SPIKE_RUN, len(r) - 1) + 1)
                if all(self._is_spike(*r[-k], r[-n - 1], motion=False)
                       for k in range(1, n + 1))]  # fmt: skip

    def suspect_from_ns(self) -> int | None:
        """While the last accepted samples may be a spike (the longest such run): the stamp of
        the one before them, past which the estimator should not go until a later sample
        decides; None otherwise."""
        runs = self._suspect_runs
        return self._recent[-runs[-1] - 1][0] if runs else None

    def _spike_run_before(self, t_ns: int, g: Vec3, a: Vec3) -> int:
        """How many of the last accepted samples (0: none) were a spike: beyond floor and noise
        from the one before them and from the sample at ``t_ns``, which agrees with that one
        (a spike two samples long passed one-sample tests: KITTI raw, ins 8.3 m off)."""
        if self._streak or not self._suspect_runs:
            return 0
        r = self._recent
        if not self._is_spike(t_ns, g, a, r[-1], motion=False):
            return 0
        return next((n for n in self._suspect_runs if not self._is_spike(t_ns, g, a, r[-n - 1])),
                    0)  # fmt: skip

    def _accept(self, t_ns: int, g: Vec3, a: Vec3) -> Verdict:
        self._streak = 0
        self.counts.accepted += 1
        retract, self._retract = self._retract, 0
        if retract:  # the last accepted samples were a spike: judged from the one before them
            self._forget_last(retract, "spike")
            base = self._recent[-1]
            self._recent.clear()
            self._recent.append(base)
        verdict = Verdict("accept", retract_previous=retract)
        if self._last is not None:
            dt = (t_ns - self._last[0]) * 1e-9
            median = self.median_spacing_s()
            # Before a spacing is seen the limit is the nominal rate's, which a recording that
            # keeps fewer samples breaks at once: such a spacing is a gap only from FIRST_GAP_S
            # (KITTI raw from 3 s: "IMU gap of 0.110 s", a user's probe), and stays out of the
            # median (as the median, 0.45 s made a 2 s dropout after it no gap: a review).
            over = median is not None and dt > self.options.gap_factor * median
            if over and (self._spacings or dt > FIRST_GAP_S):
                c = self.counts
                c.gaps += 1
                c.gap_total_s += dt
                c.longest_gap_s = max(c.longest_gap_s, dt)
                verdict = Verdict("gap", gap_s=dt, retract_previous=retract)
            elif not over:
                self._spacings.append(dt)  # gaps stay out of the median
                self._since_median += 1
                if self._since_median >= _MEDIAN_EVERY or len(self._spacings) < _MEDIAN_EVERY:
                    self._median_s, self._since_median = None, 0  # recomputed when next asked
        last = self._last
        if last is not None:
            live = self._triad_live
            live[0] = live[0] + 1 if g != last[1] else 0
            live[1] = live[1] + 1 if a != last[2] else 0
            # the last sample's values on the axes that changed since were live, not a rail
            for i, (v, v0) in enumerate(zip(g + a, last[1] + last[2], strict=True)):
                if v != v0:
                    self._live_max[i] = max(self._live_max[i], abs(v0))
                    self._axis_live[i] += 1
                else:
                    self._axis_live[i] = 0
        self._recent.append((t_ns, g, a))
        self._suspect_runs = self._runs_of_suspects()
        return verdict

    def summary(self) -> dict[str, object]:
        """Counters for ``report.json``: accepted, dropped per reason, gaps, re-anchorings."""
        c = self.counts
        return {
            "accepted": c.accepted,
            "dropped": dict(c.dropped),
            "gaps": c.gaps,
            "gap_total_s": c.gap_total_s,
            "longest_gap_s": c.longest_gap_s,
            "reanchored": c.reanchored,
            "median_spacing_s": self.median_spacing_s(),
        }


def _floats(v: ArrayLike) -> Vec3:
    """The numbers of ``v`` as a tuple of Python floats (``tolist`` is the fast way for arrays)."""
    if isinstance(v, np.ndarray):
        return tuple(v.astype(float, copy=False).ravel().tolist())  # type: ignore[return-value]
    return tuple(float(x) for x in np.ravel(v))  # type: ignore[return-value]


def gap_covariance(gap_s: float, accel_std: float, gyro_std: float) -> NDArray[np.float64]:
    """Covariance (9, 9) of (δp, δv, δθ) added by bridging ``gap_s`` seconds without samples.

    Across a gap the integrator holds the last specific force and rate, so their error is a
    constant over the gap, not white noise: with a per-axis std ``accel_std`` (m/s²) and
    ``gyro_std`` (rad/s) of that error, ``δv = δa T``, ``δp = δa T²/2``, ``δθ = δω T``, which
    gives ``var_p = σa² T⁴/4``, ``cov_pv = σa² T³/2``, ``var_v = σa² T²``, ``var_θ = σω² T²``
    per axis (the tilt's coupling into velocity is left to the filter's own propagation). The
    sensors' white noise over the gap is far smaller and is already in the process noise. A
    fair ``accel_std``/``gyro_std`` is the spread of the samples in the second before the gap.
    """
    T = float(gap_s)
    sa2, sw2 = float(accel_std) ** 2, float(gyro_std) ** 2
    Q = np.zeros((9, 9))
    eye = np.eye(3)
    Q[0:3, 0:3] = sa2 * T**4 / 4 * eye
    Q[0:3, 3:6] = Q[3:6, 0:3] = sa2 * T**3 / 2 * eye
    Q[3:6, 3:6] = sa2 * T**2 * eye
    Q[6:9, 6:9] = sw2 * T**2 * eye
    return Q
