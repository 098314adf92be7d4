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
the gates then widen by themselves. Pure logic; the core applies the actions.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

RecoveryKind = Literal["inflate", "reset"]


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


@dataclass(frozen=True)
class RecoveryAction:
    """What the core should do: ``inflate`` the covariance by ``inflate_factor`` or ``reset``
    position and velocity from GPS; ``sensors`` are those found rejecting."""

    kind: RecoveryKind
    reason: str
    sensors: tuple[str, ...]
    inflate_factor: float = 1.0


@dataclass
class _SensorTrack:
    nis_per_dof: deque[float]
    consecutive_rejections: int = 0
    last_rejection_ns: int | None = None
    last_accepted_ns: int | None = None
    fused: int = 0
    rejected: int = 0


@dataclass
class ConsistencyMonitor:
    """Feed it every gated update; ask :meth:`should_recover` after each batch of updates."""

    options: ConsistencyOptions = field(default_factory=ConsistencyOptions)
    inflations: int = 0
    resets: int = 0
    _sensors: dict[str, _SensorTrack] = field(default_factory=dict)
    _last_inflation_ns: int | None = None
    _events: list[dict[str, object]] = field(default_factory=list)

    def observe(self, sensor: str, accepted: bool, nis: float, dof: int, t_ns: int) -> None:
        """Record one update of ``sensor`` at ``t_ns``: gate outcome and NIS with ``dof``."""
        s = self._sensors.get(sensor)
        if s is None:
            s = self._sensors[sensor] = _SensorTrack(deque(maxlen=self.options.window))
        if np.isfinite(nis) and dof > 0:
            s.nis_per_dof.append(float(nis) / dof)
        if accepted:
            s.fused += 1
            s.consecutive_rejections = 0
            s.last_accepted_ns = int(t_ns)
        else:
            s.rejected += 1
            s.consecutive_rejections += 1
            s.last_rejection_ns = int(t_ns)

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
        return action

    def nis_mean(self, sensor: str) -> float | None:
        """Mean NIS per degree of freedom of ``sensor`` over the window (1 when consistent)."""
        s = self._sensors.get(sensor)
        return float(np.mean(s.nis_per_dof)) if s is not None and s.nis_per_dof else None

    def summary(self) -> dict[str, object]:
        """For ``report.json``: inflations, resets, their times, windowed NIS per sensor."""
        return {
            "inflations": self.inflations,
            "resets": self.resets,
            "events": list(self._events),
            "nis_per_dof_window": {name: self.nis_mean(name) for name in sorted(self._sensors)},
        }
