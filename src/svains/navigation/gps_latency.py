"""GPS stamps against the IMU's clock: a receiver's latency, found from velocity changes.

A fix stamped when it reached the computer, not when it held (NMEA read from a serial port, a
driver stamping on arrival), lags the IMU by the receiver's latency, often 50-200 ms. The
filter then fuses each fix against the state of a moment later and follows a late trajectory
(KITTI raw ``ins`` with the fixes stamped 0.1 s late: 0.81 m position RMSE against 0.28 m).
Nothing else says so: each fix passes its gate.

Between two fixes 0.5-3 s apart (consecutive at 1 Hz; a faster receiver's fixes in between
passed over) the GPS velocity changes by ``Δv_GPS``; the IMU says how the velocity changed
over any interval: its specific force, turned into the world frame from the filter's attitude
at the first fix by the gyro (biases removed), plus gravity, integrated (and the lever arm's
``R (ω × p_B_G)`` at both ends). A GPS whose fixes hold ``τ`` before their stamps changes its
velocity as the IMU's did over the interval shifted back by ``τ``. Each shift on a grid
(``-MAX_EARLY_S`` … ``MAX_LATE_S``, ``STEP_S``) is scored by its deviance over the steps,
``Σ |Δv_GPS - Δv_IMU(τ)|² / σ² + log σ²`` per axis, ``σ²`` the step's variance at that shift
(``_variance``: both fixes' velocity noise, ``MODEL_STD_MPS²``, the accelerometer's white
noise, and on the horizontal axes the tilt the gyro's random walk leaks, which grows with the
distance of the shifted interval from the attitude's anchor). The best shift is the latency,
its standard deviation half the width of the shifts within one (scaled) unit of deviance of
it. Only a change of acceleration shows a shift (a constant acceleration integrates the same
over any shifted interval): braking, pulling away, the entry and exit of turns. Unlike the GPS
course against the gyro's turns, this needs no assumption about the vehicle: a car's course
lags its heading in a turn (KITTI raw: by 80 ms by that measure) and a multicopter's velocity
need not follow its heading at all.

A latency of ``WARN_MS`` or more, from at least ``MIN_STEPS`` steps whose velocity changes it
explains (misfit per degree of freedom at most ``MAX_FIT``) and that the stamps as given fit
worse in deviance by ``MIN_DELTA_DEVIANCE`` and by ``MIN_DELTA_PER_STEP`` per step (scaled by the
misfit per degree of freedom when above 1), is warned once. Per step, since a model error
(the simulator's very noisy gyro, KITTI raw's OXTS velocities lagging its own accelerations
by about 60 ms while its positions fit unshifted) sums over steps as a latency does, but at
about 0.3-0.5 per step against 3 per step for KITTI raw's fixes stamped 0.1 s late. The
warning gives the ``timeshift_gps_imu`` to set; a best shift at the grid's edge is warned as
beyond it. A step is judged once the IMU history reaches ``MAX_EARLY_S`` past its second fix
(at a later fix); steps across an IMU fault are skipped by the caller. Costs a few hundred
3x3 products per step.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from svains.geometry.rotation import quat_to_rotmat
from svains.navigation.imu_history import ImuHistory, gyro_attitudes, shifted_integrals

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

MAX_EARLY_S = 0.2  # fixes stamped before they hold (rare): searched this far
MAX_LATE_S = 0.5  # fixes stamped after they hold (arrival stamps): searched this far
STEP_S = 0.01
STEP_MIN_S, STEP_MAX_S = 0.5, 3.0  # consecutive fixes this far apart make a step
MODEL_STD_MPS = 0.05  # per axis and step: attitude (0.3° of tilt is 0.05 m/s per s) and accel
MIN_STEPS = 10
LEVER_SMOOTH_S = 0.1  # s: the gyro averaged over this for the lever arm's velocity
MAX_FIT = 10.0
WARN_MS = 40.0
MIN_DELTA_DEVIANCE = 50.0  # how much worse the stamps as given must fit than the best shift
MIN_DELTA_PER_STEP = 1.5  # and per step: an effect, not a model error summed over many steps


@dataclass
class _Fix:
    t_ns: int
    v_W_G: F64  # (3,) m/s
    R_W_B: F64  # (3, 3), the filter's attitude at the fix
    b_g: F64  # (3,) rad/s
    b_a: F64  # (3,) m/s²


@dataclass
class GpsLatencyCheck:
    """Misfit of the GPS velocity changes per shift of the GPS stamps (module docstring).
    ``g_W`` (3,) m/s², ``p_B_G`` (3,) m the antenna's lever arm, ``velocity_noise_std`` m/s
    the GPS velocity's per axis."""

    history: ImuHistory
    g_W: F64
    p_B_G: F64
    velocity_noise_std: float
    gyro_noise_density: float = 0.0  # rad/s/√Hz: the attitude's random walk over a step
    accel_noise_density: float = 0.0  # m/s²/√Hz
    shifts_s: F64 = field(default_factory=lambda: np.arange(
        -MAX_EARLY_S, MAX_LATE_S + STEP_S / 2, STEP_S))  # fmt: skip
    chi2: F64 = field(init=False)
    deviance: F64 = field(init=False)
    steps: int = 0
    warned: str | None = None
    _last: _Fix | None = None
    _pending: list[tuple[_Fix, _Fix]] = field(default_factory=list)

    @property
    def last_fix_ns(self) -> int | None:
        """Time of the fix the next step starts from (None before any)."""
        return None if self._last is None else self._last.t_ns

    def __post_init__(self) -> None:
        self.chi2 = np.zeros(self.shifts_s.size)
        self.deviance = np.zeros(self.shifts_s.size)
        self.g_W = np.asarray(self.g_W, float)
        self.p_B_G = np.asarray(self.p_B_G, float)

    def observe_fix(self, t_ns: int, v_W_G: F64, q_W_B_wxyz: F64, b_g: F64, b_a: F64,
                    usable: bool = True) -> None:  # fmt: skip
        """A GPS fix at ``t_ns`` with velocity ``v_W_G`` (3,) m/s and the filter's attitude and
        biases there; ``usable=False`` (an IMU fault since the step's first fix) starts afresh.
        A step runs from its first fix to the first fix ``STEP_MIN_S`` or more after it (a
        5-10 Hz receiver's fixes in between are passed over), which starts the next."""
        last = self._last
        if usable and last is not None and t_ns - last.t_ns < STEP_MIN_S * 1e9:
            return
        fix = _Fix(int(t_ns), np.asarray(v_W_G, float).copy(),
                   np.asarray(quat_to_rotmat(np.asarray(q_W_B_wxyz, float)), float),
                   np.asarray(b_g, float).copy(), np.asarray(b_a, float).copy())  # fmt: skip
        self._last = fix
        if usable and last is not None and fix.t_ns - last.t_ns <= STEP_MAX_S * 1e9:
            self._pending.append((last, fix))
        self.poll()

    def poll(self) -> None:
        """Judge the pending steps the IMU history now covers."""
        t = self.history.t_ns
        if t.size < 2:
            return
        keep = []
        for a, b in self._pending:
            if t[-1] < b.t_ns + MAX_EARLY_S * 1e9:
                keep.append((a, b))
                continue
            dv = self._imu_dv(a, b)
            if dv is not None:
                var = self._variance((b.t_ns - a.t_ns) * 1e-9)
                r = (b.v_W_G - a.v_W_G)[None, :] - dv
                self.chi2 += np.sum(r * r / var, axis=1)
                self.deviance += np.sum(r * r / var + np.log(var), axis=1)
                self.steps += 1
        self._pending = keep
        self._judge()

    def _variance(self, d_s: float) -> F64:
        """Per shift and axis (S, 3) m²/s²: the variance of a step's residual over ``d_s``
        seconds. Both fixes' velocity noise, the model's, the accelerometer's white noise, and
        on the horizontal axes gravity leaking through the attitude's random walk from the
        first fix, whose anchor lies at a different place in each shifted interval: the
        integral of a random walk over ``[c, c + L]`` from its anchor has variance ``L² c +
        L³/3`` (``c >= 0``), over ``[-a, b]`` around it ``(a³ + b³)/3``. Unequal variances,
        so the shifts are compared by their deviance (``Σ r²/σ² + log σ²``), not χ²."""
        s0, s1 = -self.shifts_s, d_s - self.shifts_s
        walk = np.where(
            s0 >= 0.0, d_s**2 * s0 + d_s**3 / 3.0,
            np.where(s1 <= 0.0, d_s**2 * -s1 + d_s**3 / 3.0,
                     (np.abs(s0) ** 3 + np.maximum(s1, 0.0) ** 3) / 3.0),
        )  # fmt: skip
        g2 = float(self.g_W @ self.g_W)
        base = (2.0 * self.velocity_noise_std**2 + MODEL_STD_MPS**2
                + self.accel_noise_density**2 * d_s)  # fmt: skip
        tilt = g2 * self.gyro_noise_density**2 * walk
        up = np.abs(self.g_W) / np.sqrt(g2)  # the vertical axis takes no tilt leak
        return base + tilt[:, None] * (1.0 - up)[None, :]

    def _imu_dv(self, a: _Fix, b: _Fix) -> F64 | None:
        """The IMU's velocity change of the antenna (S, 3) m/s over ``[a, b]`` shifted back
        by each shift, or None when the history does not hold it."""
        h = self.history
        t = h.t_ns
        lo = a.t_ns - int(MAX_LATE_S * 1e9) - 1
        hi = b.t_ns + int(MAX_EARLY_S * 1e9) + 1
        if t[0] > lo or t[-1] < hi:
            return None
        i0 = max(int(np.searchsorted(t, lo, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(t, hi)) + 1, t.size)
        ts = (t[i0:i1] - a.t_ns) * 1e-9
        w = h.gyro_B[i0:i1] - a.b_g
        f = h.accel_B[i0:i1] - a.b_a
        R = gyro_attitudes(a.R_W_B, w, ts)  # the filter's attitude at the first fix, turned
        acc = np.einsum("nij,nj->ni", R, f) + self.g_W
        d = (b.t_ns - a.t_ns) * 1e-9
        dv = shifted_integrals(ts, acc, d, -self.shifts_s)  # shifted back by each shift
        if not self.p_B_G.any():
            return dv
        # ω averaged over LEVER_SMOOTH_S: one sample's gyro noise times the lever arm (the
        # simulator's 0.12 rad/s by 1.8 m: 0.2 m/s, twice the GPS's velocity noise) made a
        # latency of 120 ms out of nothing (a user's probe)
        n = max(1, round(LEVER_SMOOTH_S / max(float(np.median(np.diff(ts))), 1e-6)))
        box = np.ones(n)
        count = np.convolve(np.ones(len(w)), box, mode="same")  # fewer samples at the ends
        w_mean = np.stack([np.convolve(w[:, i], box, mode="same") / count
                           for i in range(3)], axis=1)  # fmt: skip
        lever = np.einsum("nij,nj->ni", R, np.cross(w_mean, self.p_B_G))  # R (ω × p_B_G)
        return dv + np.stack([np.interp(d - self.shifts_s, ts, lever[:, i])
                              - np.interp(-self.shifts_s, ts, lever[:, i])
                              for i in range(3)], axis=1)  # fmt: skip

    def figures(self) -> tuple[float, float, float, float] | None:
        """(latency s, its standard deviation s, misfit per degree of freedom at the best shift,
        how much worse the stamps as given fit: ``(χ²(0) - χ²_min)`` over the misfit per
        degree of freedom when above 1); None before ``MIN_STEPS`` steps. The standard
        deviation is half the width of the shifts within one (scaled) unit of the minimum."""
        if self.steps < MIN_STEPS:
            return None
        k = int(np.argmin(self.deviance))
        fit = float(self.chi2[k]) / (3 * self.steps - 1)
        scale = max(fit, 1.0)
        inside = self.deviance <= self.deviance[k] + scale
        lo = hi = k
        while lo > 0 and inside[lo - 1]:
            lo -= 1
        while hi < inside.size - 1 and inside[hi + 1]:
            hi += 1
        std = max(0.5 * float(self.shifts_s[hi] - self.shifts_s[lo]), STEP_S)
        zero = int(np.argmin(np.abs(self.shifts_s)))
        delta = float(self.deviance[zero] - self.deviance[k]) / scale
        return float(self.shifts_s[k]), std, fit, delta

    def _shown(self, got: tuple[float, float, float, float]) -> str | None:
        """What the figures ``got`` show beyond a model error: ``beyond`` (the best shift at
        the grid's edge), ``shift`` (inside it) or None (the stamps as given fit about as
        well, or the best shift does not explain the steps): the warning's tests."""
        lag, _, fit, delta = got
        if delta < max(MIN_DELTA_DEVIANCE, MIN_DELTA_PER_STEP * self.steps):
            return None
        edge = lag <= self.shifts_s[0] + STEP_S / 2 or lag >= self.shifts_s[-1] - STEP_S / 2
        if edge:
            return "beyond"
        return None if fit > MAX_FIT else "shift"

    def _judge(self) -> None:
        got = self.figures()
        if got is None or self.warned is not None:
            return
        lag, std, _, _ = got
        shown = self._shown(got)
        if shown is None:
            return
        edge = shown == "beyond"
        # A shift beyond the grid cannot fit at its edge: warned whatever the misfit, as long
        # as the edge explains the steps far better than the stamps as given.
        if edge:
            self.warned = "beyond"
            log.warning(
                "online input: the GPS velocity changes match the IMU's best with the fixes' "
                "stamps shifted by %+.0f ms, the edge of the %+.0f … %+.0f ms searched: are "
                "they stamped on another clock?", -1e3 * lag, -1e3 * MAX_LATE_S,
                1e3 * MAX_EARLY_S)  # fmt: skip
        elif abs(lag) * 1e3 >= WARN_MS:
            self.warned = "latency"
            log.warning(
                "online input: the GPS fixes %s the IMU by %.0f ± %.0f ms (their velocity "
                "changes against the IMU's over %d steps): give timeshift_gps_imu: %.3f in "
                "gps0/sensor.yaml", "lag" if lag > 0 else "lead", 1e3 * abs(lag), 1e3 * std,
                self.steps, -lag)  # fmt: skip

    def summary(self) -> dict[str, object]:
        """``latency_ms`` (positive: stamped late), ``latency_std_ms``, ``latency_fit``,
        ``delta_deviance`` (None before enough steps), ``shown`` (whether the best shift
        stands out of a model error: ``_shown``'s tests; False: ``latency_ms`` is no
        measure, whatever its standard deviation), ``steps`` and ``warned`` (None,
        ``latency`` or ``beyond``)."""
        got = self.figures()
        return {"latency_ms": None if got is None else 1e3 * got[0],
                "latency_std_ms": None if got is None else 1e3 * got[1],
                "latency_fit": None if got is None else got[2],
                "delta_deviance": None if got is None else got[3],
                "shown": got is not None and self._shown(got) is not None,
                "steps": self.steps, "warned": self.warned}  # fmt: skip
