"""Divergence detection: windowed NIS per sensor and consecutive rejections across sensors.

A filter that has lost itself (after an IMU fault, say) rejects every correct measurement: its
chi-square gates compare the sensors with a wrong state it is sure of. The monitor watches the
gating outcome of every update (:meth:`ConsistencyMonitor.observe`) and, when independent
sensors are rejected together while the covariance is small, asks for a recovery
(:meth:`ConsistencyMonitor.should_recover`):

1. first ``inflate``: the core multiplies the covariance of position, velocity and attitude by
   ``inflate_factor``, so the next measurements pass the gate and pull the state back;
2. if the rejections go on within ``escalate_within_s`` of an inflation, ``reset``: the core
   re-initialises position and velocity from the next GPS fix (attitude too where a sensor
   gives it).

"Lost" means: at least ``min_sensors`` sensors each with ``min_consecutive`` rejections in a row,
the latest within ``window_s``; or an absolute-position sensor (``anchor_sensors``, GPS) alone
rejected that often, since nothing else can contradict it; or, in a run without an anchor
sensor (``anchor_in_use`` false: GPS-denied), a vision sensor (``standalone_sensors``) alone,
whose refused frames would otherwise leave the filter on the IMU for good; such a run has no
GPS to reset from, so its escalation inflates again. A filter whose anchor sensor was
fused within ``window_s`` (and not rejected since) is not lost. A large covariance is not lost:
the gates then widen by themselves.

An anchor sensor that *jumps* is not evidence that the filter is lost: its first rejected
update came right after an accepted one (within ``jump_window_s``), its NIS at least
``jump_factor`` times the gate's threshold (an abrupt step, not the growing innovations of a
drifting filter), with no IMU fault since the accepted one (``note_imu_fault``), and its NIS
not growing past ``jump_growth`` times the first since (a constant offset, not a velocity
error that grows with time). While only such sensors reject, the monitor answers ``distrust``
(the core warns and keeps rejecting them): IMU and vision contradict the jump, so the filter does
not follow a GPS offset by a multipath or a datum change. Other sensors rejecting as well still
make the filter lost. The jump is adopted only when the filter's own uncertainty has grown to
pass the gate, and then only when its innovation is nearer zero than the jump's own
(:meth:`jump_offsets`, for ``jump_hold_s``): a growing spread alone lets the gate pass the
offset too (KITTI raw, `ins`, GPS 50 m off from 10 s: adopted 24 s later, 15.8 m RMSE against
11.6 m with those fixes removed). In a GPS-denied run a vision sensor, which may then call for
a recovery alone, is tested for jumps the same way: a camera stuck on one scene (blocked, a
replayed frame) contradicts the IMU as abruptly as a jumped GPS, and an inflation would hand
the filter to it (KITTI raw, 3 s of one scene with new noise: 12 m instead of 0.30 m). Pure
logic; the core applies the actions.

Growth alone does not tell a drifting filter from an anchor that has turned erratic
(multipath: every fix off by its own metres, now and then inside the gate): both give large
rejected innovations, some larger than the first. A drifting filter moves them along a trend
in time (a velocity error, a tilt integrating into position), multipath scatters them.
``_erratic`` fits a quadratic in time (``TREND_TERMS``) to the innovations from the last
accepted update on, whitened by the latest innovation covariance, and compares the scatter
about it with the chi-square quantile ``jump_erratic_probability``. A jump is withdrawn only
when its innovations grew and follow a trend; an anchor rejected alone is lost only along a
trend, and scattered it is distrusted (warned: ``multipath?``). Three rejected fixes and the
accepted one before them leave one degree of freedom per axis about the quadratic; while the
fixes' velocity (``rate_channels``) agrees with the filter, which a drifting filter's would
not, the monitor waits ``rate_patience`` fixes more. A trend is still not always the
filter's: a filter error obeys kinematics (its position innovation grows at the rate its
velocity innovation shows), so positions that run off while the velocity agrees are a
wandering receiver solution, distrusted (``_drifting_anchor``). KITTI raw, `ins`, 10 s of
fixes with 10 m of noise per axis: position RMSE 6.99 m (the filter inflated and fused the
noise) against 0.51 m with those fixes removed; now 0.51 m.

The rate channel also tells a receiver whose velocity alone is wrong (a failed Doppler
solution, a velocity in another frame): when an anchor jumped and, in every rejected update
since, its rate channel is outside its own gate while the rest is inside its own, the monitor
answers ``drop_rate`` and the core fuses the sensor without that channel for a while
(``FaultOptions.gps_velocity_drop_s``) instead of refusing whole fixes whose position is
right. Only after a jump: a drifting filter shows in its velocity first too, but growing.

A sensor can also mislead from inside its gate: a magnetometer near steel, turned by a few
degrees, passes sample by sample and the heading follows. :meth:`ConsistencyMonitor.leaning`
tests the last ``lean_window`` accepted whitened innovations of ``lean_sensors`` for a common
offset (as the bias test does GPS's) and answers ``hold``: the core stops fusing the sensor
for a while (``FaultOptions.lean_hold_s``).

An IMU bias that *steps* (a knocked or overheated IMU) leaves every gate passing for seconds:
the filter, sure of the old bias, takes the step for a tilt or a velocity and its innovations
stay small but lean one way. :meth:`ConsistencyMonitor.biased` tests the last ``bias_window``
accepted whitened innovations of a low-dimensional absolute sensor (``bias_sensors``, GPS) for
a common offset: with ``w_k = L_k^-1 r_k`` (``S_k = L_k L_k^T``) white and unit under a
consistent filter, ``N |mean(w)|^2`` is chi-square with the sensor's dimension. Above its
``bias_probability`` quantile the monitor answers ``bias``: the core widens the covariance of
the IMU biases, so the next updates can move them, and that of attitude and velocity by what
the widened biases would have done since the middle of the window (the step happened inside
it). Rejected updates are left out: they are a jump's or a lost filter's, handled above. A
window never spans an outage of the sensor (a spacing over ``BIAS_WINDOW_MAX_GAP_S`` and twice
the one before, :func:`_window_broken`): the first fixes after an outage correct what the INS
drifted there, and a window stretched over the outage would size the attitude and velocity
spread of the widening by the whole outage (a simulated village flight, seed 5: 6 m/s and 17°
from a window of 12 s, which the next vision update could not linearise).

Vision updates feed the same test when the core puts them among ``bias_sensors`` (GPS-aided
runs; GPS-denied ones on request, ``FaultOptions.bias_test_vision_gps_denied``), through their
corrections rather than their innovations (hundreds of pixels): the correction of velocity and
attitude ``K r`` whitened by the covariance the update removed
(``fault_handling.whitened_correction``), white and unit under a consistent filter. A gyro bias
step turns the heading between frames the same way every time, which each frame then corrects,
so the corrections lean long before any GPS innovation does (a +0.05 rad/s step: an alarm 1.5 s
after it from vision, 8 s from GPS). Frames come faster than fixes, so they have their own
window and quantile (``vision_bias_window``, ``vision_bias_probability``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from svains.filter import chi2_gate

RecoveryKind = Literal["inflate", "reset", "distrust", "bias", "drop_rate", "hold"]


@dataclass(frozen=True)
class ConsistencyOptions:
    """Thresholds of :class:`ConsistencyMonitor`."""

    window: int = 20  # updates per sensor in the windowed NIS
    min_consecutive: int = 3  # rejections in a row that make a sensor "rejecting"
    window_s: float = 5.0  # s, a rejecting sensor's last rejection is at most this old
    min_sensors: int = 2  # independent sensors rejecting together
    anchor_sensors: tuple[str, ...] = ("gps",)  # absolute position: alone is enough
    max_position_std_m: float = 10.0  # m, above it the covariance is not "small"
    inflate_factor: float = 100.0  # variance factor on position, velocity and attitude
    escalate_within_s: float = 5.0  # s, rejections this soon after an inflation: reset
    # Sensors that may call for a recovery alone when the run has no anchor sensor (GPS-denied
    # vision: nothing else can contradict it; refused frames would add IMU-only drift forever).
    standalone_sensors: tuple[str, ...] = ("tc", "3d", "lc")
    anchor_in_use: bool = True  # the run fuses an anchor sensor (GPS): resets are possible
    # An anchor's rejection at most this long after its last accepted update, with a NIS at
    # least jump_factor times the gate's threshold, is a jump of the sensor (see the module).
    jump_window_s: float = 3.0
    jump_factor: float = 10.0
    # A jump whose later NIS grows past jump_growth times its first is the filter drifting off
    # (a velocity error: the offset grows with time), not a sensor's constant offset.
    jump_growth: float = 2.0
    # ...unless its innovations since the jump scatter about a quadratic in time beyond
    # this chi-square quantile (``_erratic``: a sensor gone erratic, multipath; None: no test).
    jump_erratic_probability: float | None = 1 - 1e-6
    # Components [start, stop) of an anchor's innovation that are its rate channel (GPS
    # velocity, when the update has it: dof == stop). A drifting filter is off in its rate
    # too; while that channel agrees (inside its own gate at ``rate_probability``) in every
    # rejected update, the anchor's rejections wait for ``rate_patience`` more fixes before
    # the filter is taken for lost, so the scatter test has the points to tell multipath.
    # (``InsFilter.gps_block`` stacks position, then velocity)
    rate_channels: tuple[tuple[str, int, int], ...] = (("gps", 3, 6),)
    rate_probability: float = 0.999
    rate_patience: int = 1
    # When the rate channel alone disagrees in every rejected update of an anchor rejected
    # alone (the rest inside its gate), answer ``drop_rate`` (False: handled as any rejection)
    rate_drop: bool = True
    # A heading sensor disturbed by nearby steel (magnetometer) passes its gate sample by
    # sample but leans: the last ``lean_window`` accepted whitened innovations of a
    # ``lean_sensors`` share an offset beyond the ``lean_probability`` quantile -> ``hold``:
    # the core stops fusing it for a while (None: no test).
    lean_sensors: tuple[str, ...] = ("mag",)
    lean_window: int = 5
    lean_probability: float | None = 0.9999
    # While a jump lasts, at most this long (s), the anchor's updates are refused even inside
    # the gate when their innovation is nearer the jump's than zero (``jump_offsets``): the
    # filter's own spread, growing without the sensor, would otherwise let the offset in.
    jump_hold_s: float | None = 60.0
    # The bias-step test (see the module): sensors, window (accepted updates) and the chi-square
    # probability of its threshold (None: off, the default; see ``FaultOptions``).
    bias_sensors: tuple[str, ...] = ("gps",)
    bias_window: int = 3
    bias_probability: float | None = None
    # An IMU bias step moves a sensor's rate channel too (GPS velocity: the step's velocity
    # error grows at once); a window whose rate channel, whitened on its own, shares no offset
    # beyond this quantile leans in position only, a fault of the sensor (a slow GPS ramp),
    # and raises no alarm (None: no such condition; ``FaultOptions``).
    bias_rate_probability: float | None = None
    # The same test on vision updates' whitened corrections (``standalone_sensors`` among
    # ``bias_sensors``): its own window (accepted frames) and quantile (frames come faster).
    vision_bias_window: int = 3
    vision_bias_probability: float | None = None  # None: vision sensors take no test


@dataclass(frozen=True)
class RecoveryAction:
    """What the core should do: ``inflate`` the covariance by ``inflate_factor``, ``reset``
    position and velocity from GPS, ``distrust``: nothing but a warning (the only rejecting
    sensors jumped, see the module), ``bias``: widen the IMU biases' covariance (a sensor's
    innovations lean one way), or ``drop_rate``: fuse the ``sensors`` without their rate
    channel for a while (``rate_channels``: it alone disagrees); ``sensors`` are those found
    rejecting or leaning."""

    kind: RecoveryKind
    reason: str
    sensors: tuple[str, ...]
    inflate_factor: float = 1.0
    window_s: float = 0.0  # ``bias``: the time spanned by the innovations that lean (s)


# s: a spacing of accepted fixes longer than this (and twice the one before) starts a new bias
# test window (see the module)
BIAS_WINDOW_MAX_GAP_S = 2.0
# s: a bias test window's fixes (not frames) are at least this far apart (a faster GPS's fixes
# between them are left out of it): tested at every one of a 50 Hz GPS's fixes, 3 fixes 40 ms
# apart raised 25 false alarms in a 20 s simulated flight, two confirmed, the attitude 26° off
# (σ 5°; a probe). The test's false-alarm rate is then the 1-2 Hz GPS's it was set on.
BIAS_WINDOW_MIN_SPACING_S = 0.5


def _window_broken(last_ns: int | None, spacing_ns: int | None, t_ns: int) -> bool:
    """Whether an accepted fix at ``t_ns`` comes after an outage of its sensor: more than
    ``BIAS_WINDOW_MAX_GAP_S`` after the last one (``last_ns``) and, when the spacing before
    that one is known (``spacing_ns``), more than twice it (a slow sensor keeps its windows)."""
    if last_ns is None:
        return False
    gap_ns = t_ns - last_ns
    if gap_ns <= BIAS_WINDOW_MAX_GAP_S * 1e9:
        return False
    return spacing_ns is None or gap_ns > 2 * spacing_ns


# Terms of the trend a drifting filter moves its innovations along: constant, velocity and
# attitude errors (a tilt integrates into a position error quadratic in time).
TREND_TERMS = 3


def _erratic(track: list[tuple[int, np.ndarray]], cov: np.ndarray,
             probability: float | None) -> bool:  # fmt: skip
    """Whether the innovations of ``track`` (rejected updates since a jump), whitened alike by
    ``cov`` (the latest innovation covariance, the widest: a conservative scale that keeps
    their trend's shape), scatter about their best quadratic in time (``TREND_TERMS``) beyond
    the ``probability`` quantile of the chi-square with (n - 3) x dof degrees of freedom: a
    filter that drifts off (a velocity or attitude error) moves its innovations along a trend,
    a sensor that has turned erratic (multipath) scatters them. Too few updates, mixed sizes
    or no probability: False."""
    sizes = {r.shape for _, r in track}
    if probability is None or len(track) < TREND_TERMS + 1 or sizes != {(cov.shape[0],)}:
        return False
    t_s = np.array([t for t, _ in track], float) * 1e-9
    t_s -= t_s.mean()
    try:
        L = np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        return False
    W = np.linalg.solve(L, np.stack([r for _, r in track]).T).T
    A = np.column_stack([t_s**k for k in range(TREND_TERMS)])
    beta, *_ = np.linalg.lstsq(A, W, rcond=None)
    ssr = float(np.sum((W - A @ beta) ** 2))
    return ssr > chi2_gate(probability, (len(track) - TREND_TERMS) * W.shape[1])


def _common_offset(W: np.ndarray) -> float:
    """``N |mean(w)|^2`` of N whitened innovations ``W`` (N, d): chi-square with d degrees of
    freedom when they are white and unit, larger when they share an offset."""
    return float(W.shape[0] * np.sum(W.mean(axis=0) ** 2))


def _inside(r: np.ndarray, C: np.ndarray, probability: float) -> bool | None:
    """Whether ``r`` (d,) with covariance ``C`` (d, d) is inside the chi-square(d) gate at
    ``probability``; None when ``r`` is empty or ``C`` singular."""
    if r.size == 0:
        return None
    try:
        nis = float(r @ np.linalg.solve(C, r))
    except np.linalg.LinAlgError:
        return None
    return nis <= chi2_gate(probability, r.size)


@dataclass
class _SensorTrack:
    nis_per_dof: deque[float]
    consecutive_rejections: int = 0
    last_rejection_ns: int | None = None
    last_accepted_ns: int | None = None
    fused: int = 0
    rejected: int = 0
    jump_ns: int | None = None  # the current rejections began with a jump of the sensor
    jump_nis: float = 0.0
    jump_residual: np.ndarray | None = None  # the innovation of the jump's first update
    # (t_ns, innovation) of the updates since the jump, from the accepted one before it
    # (erratic or a trend)
    jump_track: list[tuple[int, np.ndarray]] = field(default_factory=list)
    jump_grew: bool = False  # an innovation since the jump passed jump_growth times its NIS
    # (t_ns, innovation) of the last accepted update and the run of rejections after it,
    # and their innovation covariances where known (the latest last)
    streak: list[tuple[int, np.ndarray]] = field(default_factory=list)
    streak_covs: list[np.ndarray] = field(default_factory=list)
    streak_rate_agrees: bool = True  # the rate channel agreed in every rejection of the run
    streak_rate_alone: bool = True  # ...or it alone disagreed in every one (the rest agreed)
    # (t_ns, whitened innovation, its rate channel whitened on its own or None) of accepted
    # updates, for the bias test
    whitened: deque[tuple[int, np.ndarray, np.ndarray | None]] = field(default_factory=deque)
    fix_spacing_ns: int | None = None  # between the last two accepted updates
    lean: deque[np.ndarray] = field(default_factory=deque)  # lean test's whitened innovations


@dataclass
class ConsistencyMonitor:
    """Feed it every gated update; ask :meth:`should_recover` after each batch of updates."""

    options: ConsistencyOptions = field(default_factory=ConsistencyOptions)
    inflations: int = 0
    resets: int = 0
    _sensors: dict[str, _SensorTrack] = field(default_factory=dict)
    jumps: int = 0
    filter_moved: int = 0  # refused frames whose camera carried on (``note_filter_moved``)
    bias_shifts: int = 0
    rate_drops: int = 0
    holds: int = 0
    _last_inflation_ns: int | None = None
    _last_imu_fault_ns: int | None = None
    _events: list[dict[str, object]] = field(default_factory=list)

    def observe(
        self, sensor: str, accepted: bool, nis: float, dof: int, t_ns: int,
        gate: float = float("inf"), whitened: np.ndarray | None = None,
        residual: np.ndarray | None = None, innovation_cov: np.ndarray | None = None,
    ) -> None:
        """Record one update of ``sensor`` at ``t_ns``: gate outcome, NIS with ``dof``, the
        gate's NIS threshold ``gate`` (for the jump test of anchor sensors), the whitened
        innovation ``whitened`` (dof,) when the update gives it (for the bias test) and its
        innovation ``residual`` (dof,) with its covariance ``innovation_cov`` (dof, dof) (a
        jump's offset, :meth:`jump_offsets`, and the scatter test after it, ``_erratic``)."""
        o = self.options
        s = self._sensors.get(sensor)
        if s is None:
            n = o.vision_bias_window if sensor in o.standalone_sensors else o.bias_window
            s = _SensorTrack(deque(maxlen=o.window), whitened=deque(maxlen=n),
                             lean=deque(maxlen=o.lean_window))  # fmt: skip
            self._sensors[sensor] = s
        if np.isfinite(nis) and dof > 0:
            s.nis_per_dof.append(float(nis) / dof)
        if accepted:
            if (whitened is not None and o.lean_probability is not None
                    and sensor in o.lean_sensors):  # fmt: skip
                w = np.asarray(whitened, dtype=float)
                if s.lean and s.lean[-1].shape != w.shape:
                    s.lean.clear()
                s.lean.append(w)
            if whitened is not None and o.bias_probability is not None and sensor in o.bias_sensors:
                w = np.asarray(whitened, dtype=float)
                if s.whitened and (s.whitened[-1][1].shape != w.shape or _window_broken(
                        s.last_accepted_ns, s.fix_spacing_ns, int(t_ns))):
                    s.whitened.clear()  # a fix without velocity, or after an outage
                if (not s.whitened or sensor in o.standalone_sensors  # (frames: own window)
                        or int(t_ns) - s.whitened[-1][0] >= BIAS_WINDOW_MIN_SPACING_S * 1e9):
                    # the rate channel alone, only for the opt-in condition that reads it
                    rate = (None if o.bias_rate_probability is None
                            else self._rate_whitened(sensor, residual, innovation_cov))  # fmt: skip
                    s.whitened.append((int(t_ns), w, rate))
            if s.last_accepted_ns is not None:
                s.fix_spacing_ns = int(t_ns) - s.last_accepted_ns
            s.fused += 1
            s.consecutive_rejections = 0
            s.streak.clear()
            s.streak_covs.clear()
            s.streak_rate_agrees = s.streak_rate_alone = True
            if residual is not None:  # the run of rejections to come starts from it
                s.streak.append((int(t_ns), np.array(residual, float)))
                if innovation_cov is not None:
                    s.streak_covs.append(np.array(innovation_cov, float))
            s.last_accepted_ns = int(t_ns)
            s.jump_ns = None
            return
        if (self.tests_jumps(sensor) and s.consecutive_rejections == 0
                and s.last_accepted_ns is not None
                and t_ns - s.last_accepted_ns <= int(o.jump_window_s * 1e9)
                and np.isfinite(gate) and nis >= o.jump_factor * gate
                and (self._last_imu_fault_ns is None
                     or self._last_imu_fault_ns < s.last_accepted_ns)):  # fmt: skip
            s.jump_ns, s.jump_nis = int(t_ns), float(nis)
            s.jump_residual = None if residual is None else np.array(residual, dtype=float)
            # from the accepted update before it (in ``streak`` then), when it gave one
            s.jump_track = [] if residual is None else [
                *s.streak, (int(t_ns), np.array(residual, float))]
            s.jump_grew = False
            self.jumps += 1
            self._events.append({"t_ns": int(t_ns), "kind": "jump", "sensors": [sensor]})
        elif s.jump_ns is not None:
            if residual is not None:
                s.jump_track.append((int(t_ns), np.array(residual, float)))
            # With innovations and their covariance, a trend needs a few of them to be told
            # from scatter: a growth seen once is remembered until they are there.
            s.jump_grew |= not nis <= o.jump_growth * s.jump_nis
            tested = (residual is not None and innovation_cov is not None
                      and o.jump_erratic_probability is not None)  # fmt: skip
            if s.jump_grew and (not tested or (
                    len(s.jump_track) > TREND_TERMS
                    and not _erratic(s.jump_track, innovation_cov,
                                     o.jump_erratic_probability))):  # fmt: skip
                s.jump_ns = None  # the offset grows: the filter drifts, the sensor did not jump
                self._events.append({"t_ns": int(t_ns), "kind": "jump-withdrawn",
                                     "sensors": [sensor]})  # fmt: skip
        s.rejected += 1
        s.consecutive_rejections += 1
        s.last_rejection_ns = int(t_ns)
        if residual is not None and innovation_cov is not None:
            s.streak.append((int(t_ns), np.array(residual, float)))
            s.streak_covs.append(np.array(innovation_cov, float))
            rate_ok, rest_ok = self._channels(sensor, s.streak[-1][1], s.streak_covs[-1])
            s.streak_rate_agrees &= rate_ok is True
            s.streak_rate_alone &= rate_ok is False and rest_ok is True
        else:
            s.streak_rate_agrees = s.streak_rate_alone = False

    def _channels(self, sensor: str, residual: np.ndarray,
                  cov: np.ndarray) -> tuple[bool | None, bool | None]:  # fmt: skip
        """Whether the rate channel of ``sensor`` (``rate_channels``) and the rest of its
        innovation ``residual`` (covariance ``cov``) are each inside their own gate (at
        ``rate_probability``); (None, None) without such a channel in this update."""
        channel = self._rate_channel(sensor)
        if channel is None or residual.shape != (channel[1],):
            return None, None
        a, b, p = *channel, self.options.rate_probability
        return _inside(residual[a:b], cov[a:b, a:b], p), _inside(residual[:a], cov[:a, :a], p)

    def _rate_whitened(self, sensor: str, residual: np.ndarray | None,
                       cov: np.ndarray | None) -> np.ndarray | None:  # fmt: skip
        """The rate channel of ``residual`` whitened by its own block of ``cov`` (marginal, not
        conditioned on the rest as the joint whitening's later rows are), or None."""
        channel = self._rate_channel(sensor)
        if channel is None or residual is None or cov is None:
            return None
        a, b = channel
        if np.shape(residual) != (b,):
            return None
        try:
            L = np.linalg.cholesky(np.asarray(cov, float)[a:b, a:b])
        except np.linalg.LinAlgError:
            return None
        return np.linalg.solve(L, np.asarray(residual, float)[a:b])

    def _rate_channel(self, sensor: str) -> tuple[int, int] | None:
        """``sensor``'s rate channel [start, stop) (``rate_channels``), or None."""
        return next(((a, b) for n, a, b in self.options.rate_channels
                     if n == sensor and 0 <= a < b), None)  # fmt: skip

    def _erratic_anchor(self, anchors: list[str]) -> bool | None:
        """For anchors rejected alone: whether the innovations of their runs of rejections,
        from the last accepted update on, scatter about no trend (``_erratic``; True: any of
        them), or None when that is not tested (no probability, an anchor without
        innovations) or is known already: at least ``TREND_TERMS + 1`` innovations following
        a trend. False while a run is too short to tell (three rejections and the accepted
        innovation before them are enough; without that one a lost filter waits one fix
        more)."""
        o = self.options
        p = o.jump_erratic_probability
        if p is None:
            return None
        tracks = [self._sensors[n] for n in anchors]
        if any(not t.streak or not t.streak_covs for t in tracks):
            return None
        if any(len(t.streak) <= TREND_TERMS + o.rate_patience * t.streak_rate_agrees
               for t in tracks):  # fmt: skip
            return False
        if any(_erratic(t.streak, t.streak_covs[-1], p) for t in tracks):
            return True
        return None

    def _drifting_anchor(self, anchors: list[str]) -> float | None:
        """For anchors rejected alone along a trend while their rate channel agrees in every
        rejected update (``streak_rate_agrees``): the largest speed (m/s, per second of the
        innovation) at which the rest of an anchor's innovation (GPS position) moves against
        its own rate channel (GPS velocity), when that is beyond the ``rate_probability``
        quantile of chi-square with the channel's dimension; else None. A filter error obeys
        kinematics: its position innovation grows at the rate its velocity innovation shows,
        so a position that runs off while the velocity agrees is the receiver's (a wandering
        float solution), not the filter's. The slope of the position innovations (least
        squares in time) against the mean velocity innovation, their covariance from the
        run's first innovation covariance (see the code)."""
        o = self.options
        worst: float | None = None
        for name in anchors:
            t = self._sensors[name]
            channel = self._rate_channel(name)
            n = len(t.streak)
            if (channel is None or not t.streak_rate_agrees or n <= TREND_TERMS
                    or len(t.streak_covs) != n):  # fmt: skip
                return None
            a, b = channel
            if a != b - a or any(r.shape != (b,) for _, r in t.streak):
                return None  # the rest must be the rate's integral: as many components
            ts = np.array([ti for ti, _ in t.streak], float) * 1e-9
            ts -= ts.mean()
            stt = float(ts @ ts)
            if not stt > 0:
                return None
            R = np.stack([r for _, r in t.streak])
            # The filter's own error obeys kinematics and cancels from d: what is left is the
            # receiver's white noise, bounded by the run's first (smallest) covariance.
            C = t.streak_covs[0]
            d = ts @ R[:, :a] / stt - R[:, a:b].mean(axis=0)
            cov_d = C[:a, :a] / stt + C[a:b, a:b] / n
            try:
                stat = float(d @ np.linalg.solve(cov_d, d))
            except np.linalg.LinAlgError:
                return None
            if not stat > chi2_gate(o.rate_probability, a):
                return None
            speed = float(np.linalg.norm(d))
            worst = speed if worst is None else max(worst, speed)
        return worst

    def tests_jumps(self, sensor: str) -> bool:
        """Whether a rejection of ``sensor`` is tested for a jump of the sensor: an anchor
        (GPS), or a vision sensor where it may call for a recovery alone (GPS-denied)."""
        o = self.options
        return sensor in o.anchor_sensors or (not o.anchor_in_use
                                              and sensor in o.standalone_sensors)  # fmt: skip

    def jump_offsets(self, t_ns: int) -> dict[str, np.ndarray]:
        """The innovation of each anchor sensor's jump still on at ``t_ns`` (at most
        ``jump_hold_s`` after it): what its updates are tested against
        (``UKF.update_blocks``' ``offsets``) so that the filter's growing spread does not let
        the offset in. Empty without a jump or with the hold off."""
        o = self.options
        if o.jump_hold_s is None:
            return {}
        hold = int(o.jump_hold_s * 1e9)
        return {name: s.jump_residual for name, s in self._sensors.items()
                if name in o.anchor_sensors and s.jump_ns is not None
                and s.jump_residual is not None and t_ns - s.jump_ns <= hold}  # fmt: skip

    def note_filter_moved(self, sensor: str, t_ns: int) -> None:
        """``sensor``'s update refused at ``t_ns`` is the filter's error, not a jump of the
        sensor (a vision frame whose camera carried on its motion while the filter's prediction
        left it, ``navigation.camera_continuity``): as after an IMU fault, and a jump already
        taken for the sensor's is withdrawn. Call before observing that update."""
        self._last_imu_fault_ns = int(t_ns)
        s = self._sensors.get(sensor)
        if s is not None:
            s.jump_ns = None
        self.filter_moved += 1
        self._events.append({"t_ns": int(t_ns), "kind": "filter_moved", "sensors": [sensor]})

    def note_imu_fault(self, t_ns: int) -> None:
        """An IMU fault (a dropped sample, a gap) at ``t_ns``: a jump of an anchor sensor right
        after it may be the filter's own error, so it is not taken for the sensor's."""
        self._last_imu_fault_ns = int(t_ns)

    def rejecting(self, t_ns: int) -> tuple[str, ...]:
        """Sensors with ``min_consecutive`` rejections in a row, the last within ``window_s``."""
        o = self.options
        recent = int(o.window_s * 1e9)
        return tuple(
            sorted(
                name
                for name, s in self._sensors.items()
                if s.consecutive_rejections >= o.min_consecutive
                and s.last_rejection_ns is not None
                and t_ns - s.last_rejection_ns <= recent
            )
        )

    def anchored(self, t_ns: int) -> bool:
        """Whether an anchor sensor (GPS) was fused within ``window_s`` and not rejected since:
        a filter whose absolute position passes its gate is not lost, even when relative
        sensors reject (a model error on clean data, e.g. the paper model's 3d and sonar)."""
        recent = int(self.options.window_s * 1e9)
        for name in self.options.anchor_sensors:
            s = self._sensors.get(name)
            if (s is not None and s.consecutive_rejections == 0 and s.last_accepted_ns is not None
                    and t_ns - s.last_accepted_ns <= recent):  # fmt: skip
                return True
        return False

    def should_recover(self, t_ns: int, position_std_m: float) -> RecoveryAction | None:
        """The recovery to apply now, or None. ``position_std_m``: the filter's position
        standard deviation (e.g. sqrt(trace(P_pp) / 3)). Counts the action it returns."""
        o = self.options
        bad = self.rejecting(t_ns)
        anchors = [s for s in bad if s in o.anchor_sensors]
        alone = not o.anchor_in_use and any(s in o.standalone_sensors for s in bad)
        if not (len(bad) >= o.min_sensors or anchors or alone):
            return None
        if not position_std_m < o.max_position_std_m:
            return None
        if self.anchored(t_ns):
            return None
        others = [s for s in bad if s not in o.anchor_sensors]
        if (not others and anchors and o.rate_drop
                and all(self._sensors[n].streak_rate_alone and self._sensors[n].jump_ns
                        is not None for n in anchors)):  # fmt: skip
            # Only the rate (GPS velocity) disagrees, in every rejected fix, since it jumped
            # right after an accepted fix: the receiver's velocity is wrong. (A drifting
            # filter shows in its velocity first too, but growing, not as a jump.)
            for name in anchors:
                t = self._sensors[name]
                t.consecutive_rejections, t.jump_ns = 0, None
                t.streak.clear()
                t.streak_covs.clear()
            self.rate_drops += 1
            self._events.append({"t_ns": int(t_ns), "kind": "drop_rate",
                                 "sensors": list(anchors)})  # fmt: skip
            return RecoveryAction(
                "drop_rate", f"{', '.join(anchors)} rejected {o.min_consecutive}+ times in a "
                "row for its velocity alone while its position agrees: fused without its "
                "velocity for a while", tuple(anchors))
        jumped = [s for s in anchors if self._sensors[s].jump_ns is not None]
        if not others and anchors and jumped == anchors:
            s = self._sensors[anchors[0]]
            return RecoveryAction(
                "distrust", f"{', '.join(anchors)} jumped (NIS {s.jump_nis:.3g} right after an "
                "accepted update) and the other sensors agree with the IMU: its updates are "
                "rejected until they agree again", tuple(anchors))
        if not others and anchors and (erratic := self._erratic_anchor(anchors)) is not None:
            if not erratic:
                return None  # too few rejected fixes yet to tell a trend from scatter
            return RecoveryAction(
                "distrust", f"{', '.join(anchors)} rejected {o.min_consecutive}+ times in a "
                "row with innovations that scatter about no trend (multipath?): its updates "
                "are rejected until they agree again", tuple(anchors))
        if (not others and anchors and o.jump_erratic_probability is not None
                and (speed := self._drifting_anchor(anchors)) is not None):  # fmt: skip
            return RecoveryAction(
                "distrust", f"{', '.join(anchors)} rejected {o.min_consecutive}+ times in a "
                f"row, its position running off at {speed:.2g} m/s against its own velocity "
                "(a wandering solution?): its updates are rejected until they agree again",
                tuple(anchors))
        if alone and all(self.tests_jumps(n) and self._sensors[n].jump_ns is not None
                         for n in bad):  # fmt: skip
            # GPS-denied: a camera that jumps (frozen, blocked, replayed) is no lost filter.
            s = self._sensors[bad[0]]
            return RecoveryAction(
                "distrust", f"{', '.join(bad)} jumped (NIS {s.jump_nis:.3g} right after an "
                "accepted update) with no IMU fault: its updates are rejected until they "
                "agree again", tuple(bad))
        why = (
            f"{', '.join(bad)} rejected {o.min_consecutive}+ times in a row with a position "
            f"std of {position_std_m:.3g} m"
        )
        escalate = (
            self._last_inflation_ns is not None
            and t_ns - self._last_inflation_ns <= int(o.escalate_within_s * 1e9)
        )
        for name in bad:  # the evidence is used up: new rejections must build up again
            self._sensors[name].consecutive_rejections = 0
        if escalate and o.anchor_in_use:
            self.resets += 1
            self._last_inflation_ns = None
            action = RecoveryAction("reset", why + " after an inflation", bad)
        else:
            self.inflations += 1
            self._last_inflation_ns = int(t_ns)
            action = RecoveryAction("inflate", why, bad, o.inflate_factor)
        self._events.append({"t_ns": int(t_ns), "kind": action.kind, "sensors": list(bad)})
        self.clear_bias_evidence()
        return action

    def biased(self, t_ns: int) -> RecoveryAction | None:
        """``bias`` when a bias sensor's last ``bias_window`` accepted whitened innovations
        share an offset beyond the ``bias_probability`` quantile (see the module), else None.
        The evidence is used up: a new alarm needs a fresh window. Counts the action."""
        o = self.options
        if o.bias_probability is None:
            return None
        for name in o.bias_sensors:
            s = self._sensors.get(name)
            if s is None or s.whitened.maxlen is None or len(s.whitened) < s.whitened.maxlen:
                continue
            W = np.stack([w for _, w, _ in s.whitened])
            span_s = (s.whitened[-1][0] - s.whitened[0][0]) / 1e9
            stat = _common_offset(W)
            rates = [r for _, _, r in s.whitened if r is not None]
            if (o.bias_rate_probability is not None and len(rates) == len(s.whitened)
                    and _common_offset(np.stack(rates))
                    <= chi2_gate(o.bias_rate_probability, rates[0].size)):  # fmt: skip
                continue  # leans in position only: not the IMU
            vision = name in o.standalone_sensors
            p = o.vision_bias_probability if vision else o.bias_probability
            if p is None:
                continue
            what = "corrections" if vision else "innovations"
            threshold = chi2_gate(p, W.shape[1])
            if stat > threshold:
                s.whitened.clear()
                self.bias_shifts += 1
                self._events.append({"t_ns": int(t_ns), "kind": "bias", "sensors": [name]})
                return RecoveryAction(
                    "bias", f"the last {W.shape[0]} {name} {what} share an offset (chi-square "
                    f"{stat:.3g} > {threshold:.3g}, {W.shape[1]} dof): an IMU bias step?", (name,),
                    window_s=span_s)
        return None

    def last_accepted_ns(self, sensors: tuple[str, ...]) -> int | None:
        """The latest accepted (gated) update of any of ``sensors`` (None: none yet)."""
        times = [s.last_accepted_ns for name in sensors
                 if (s := self._sensors.get(name)) is not None and s.last_accepted_ns is not None]
        return max(times, default=None)

    def leaning(self, t_ns: int) -> RecoveryAction | None:
        """``hold`` for the ``lean_sensors`` whose last ``lean_window`` accepted whitened
        innovations share an offset beyond the ``lean_probability`` quantile of chi-square
        with their dimension (``N |mean(w)|^2``, as the bias test): a magnetometer near
        steel, turned by a few degrees, passes its gate sample by sample and pulls the
        heading it is meant to hold. Its window is used up; counted in ``holds``."""
        o = self.options
        if o.lean_probability is None:
            return None
        for name in o.lean_sensors:
            s = self._sensors.get(name)
            if s is None or len(s.lean) < o.lean_window:
                continue
            W = np.stack(list(s.lean))
            stat = _common_offset(W)
            threshold = chi2_gate(o.lean_probability, W.shape[1])
            if stat > threshold:
                s.lean.clear()
                self.holds += 1
                self._events.append({"t_ns": int(t_ns), "kind": "hold", "sensors": [name]})
                return RecoveryAction(
                    "hold", f"the last {W.shape[0]} {name} innovations share an offset "
                    f"(chi-square {stat:.3g} > {threshold:.3g}, {W.shape[1]} dof): a disturbed "
                    f"{name}? It is not fused for a while", (name,))
        return None

    def withdraw_jumps(self) -> tuple[str, ...]:
        """The anchor sensors refused now as jumped (see the module), that refusal withdrawn:
        the jump, its hold and its innovations forgotten, so the gate and the ordinary
        recovery judge their next updates. For a state found wrong by other means (a heading
        turned from the GPS velocities), whose anchor had contradicted it. The count of the
        run is kept (it was the filter's): zeroed, a lost filter waited three more refused
        fixes for its inflation (simulated village, `3d`, magnetometer turned 90°, seed 5:
        5.6 m against 3.9 m)."""
        out = []
        for name, s in self._sensors.items():
            if name not in self.options.anchor_sensors or s.jump_ns is None:
                continue
            s.jump_ns, s.jump_grew = None, False
            s.jump_residual = None
            s.jump_track.clear()
            s.streak.clear()
            s.streak_covs.clear()
            out.append(name)
        return tuple(out)

    def clear_bias_evidence(self) -> None:
        """Forget the bias test's window (after any recovery: the innovations start anew)."""
        for s in self._sensors.values():
            s.whitened.clear()

    def nis_mean(self, sensor: str) -> float | None:
        """Mean NIS per degree of freedom of ``sensor`` over the window (1 when consistent)."""
        s = self._sensors.get(sensor)
        return float(np.mean(s.nis_per_dof)) if s is not None and s.nis_per_dof else None

    def summary(self) -> dict[str, object]:
        """For ``report.json``: inflations, resets, their times, windowed NIS per sensor."""
        return {
            "inflations": self.inflations,
            "resets": self.resets,
            "jumps": self.jumps,
            "filter_moved": self.filter_moved,
            "bias_shifts": self.bias_shifts,
            "rate_drops": self.rate_drops,
            "holds": self.holds,
            "events": list(self._events),
            "nis_per_dof_window": {name: self.nis_mean(name) for name in sorted(self._sensors)},
        }
