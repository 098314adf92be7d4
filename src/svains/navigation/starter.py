"""``Starter``: decides the filter's initial state from the streams as they arrive.

Modes (``InitOptions.mode``): ``static`` (the first ``static_s`` seconds of IMU, magnetometer
heading, the first GPS fix as position when the rig has a GPS: waits up to ``gps_wait_s`` for
it), ``gps`` (in flight, from the first fixes spaced for their noise), ``vision`` (in
flight, from stereo odometry and the IMU; with GPS fused, its position from the nearest fix)
and a given state (``groundtruth``: the caller computed it). Each waits until the data it
averages has been released in time order, then calls ``init.initialise`` on exactly that
data, so the start equals the whole-recording computation. Until then the Navigator keeps the
released measurements in a backlog.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import replace

import numpy as np

from svains.errors import ConfigError, InitialisationError, StartFixesRefusedError
from svains.models.state import StateLayout
from svains.navigation.imu_history import ImuHistory
from svains.navigation.init import (
    GpsArrays,
    ImuArrays,
    InitData,
    InitialState,
    MagArrays,
    checked_given,
    from_vision_fit,
    given_at_sample,
    initialise,
    start_fixes,
)
from svains.navigation.options import InitOptions
from svains.navigation.vision_start import StartOdometry, fit_vision_inertial, state_at
from svains.sensors.types import Rig

# A ``vision`` start takes its heading from the magnetometer samples this near its time.
MAG_HEADING_SPAN_NS = 250_000_000
# ...and, GPS fused, its position from the fix with a velocity nearest its time within this
# span (``Starter._gps_at``).
GPS_START_SPAN_NS = 2_000_000_000
# Pairs of fixes a ``gps`` start refuses in a row (``StartFixesRefusedError``) before it stops:
# a glitch passes in one or two; a stream that never agrees is no start.
MAX_REFUSED_START_FIXES = 5

log = logging.getLogger(__name__)

# A vision start whose frames span this many times ``init.vision_window_s`` is warned: the
# IMU carries it between frames seconds apart (a probe's simulated MH_03 flights, 4 frames
# over 6-15 s at 0.5-0.2 Hz: NEES 9-2900 after an in-flight start, 5-6 from the truth).
SPARSE_START_FACTOR = 2.0
# m/s²: the acceleration a start's position interpolated between two position-only fixes
# allows for (a car's or a drone's ordinary manoeuvre).
GPS_INTERP_ACCEL_MPS2 = 2.0


class Starter:
    """Collects what the initialisation needs; ``try_start`` returns the state once decided."""

    def __init__(
        self, options: InitOptions, rig: Rig, layout: StateLayout, given: InitialState | None,
        gps_fused: bool | None = None, max_row_diff_px: float | None = 2.0,
        gps_velocity: bool = True, local_heading_wait: bool = False,
    ) -> None:
        """``gps_fused``: whether the run fuses GPS (None: when the rig has one);
        ``max_row_diff_px``: the stereo rows' tolerance of the start's odometry (``vision``);
        ``gps_velocity`` False: the fixes' velocities are not used (``use_gps_velocity``), the
        start takes them as position-only; ``local_heading_wait``: the run can hold an in-motion
        start in a local frame (``InitData.local_heading_wait``)."""
        if given is None and options.mode == "groundtruth":
            raise ConfigError("init.mode groundtruth needs the initial state (initial_state=)")
        if given is not None and options.mode != "groundtruth":
            raise ConfigError(f"an initial_state is given but init.mode is {options.mode!r}: set "
                              "init.mode groundtruth to start from it, or leave it out")
        if given is None and options.mode == "gps" and rig.gps is None:
            raise ConfigError("init.mode gps (--init gps) needs a GPS: the rig has none (a data "
                              "set without gps0/); start with --init static, vision or "
                              "groundtruth")  # fmt: skip
        self.options = options
        self.rig = rig
        self.layout = layout
        self.given = None if given is None else checked_given(given, layout)
        self.gps_fused = gps_fused
        self._gps_velocity = gps_velocity
        self.local_heading_wait = local_heading_wait
        self._mag: list[tuple[int, np.ndarray]] = []
        self._gps: list[tuple[int, np.ndarray, np.ndarray]] = []
        # the ``gps`` start's fixes chosen from ``_gps`` and whether they suffice
        # (``init.start_fixes``), kept up to date as fixes come and go
        self._picked: tuple[GpsArrays | None, bool] = (None, False)
        self._refused: list[str] = []  # the ``gps`` start's pairs of fixes refused so far
        # the latest fixes, for the ``vision`` start's position (``_gps_at``)
        self._gps_recent: collections.deque[tuple[int, np.ndarray, np.ndarray]] = (
            collections.deque())
        self.odometry = (StartOdometry(rig.cam0, rig.cam1, max_row_diff_px)
                         if given is None and options.mode == "vision" else None)  # fmt: skip

    def add_mag(self, t_ns: int, m_S: np.ndarray) -> None:
        self._mag.append((t_ns, m_S))

    def add_frame(self, t_ns: int, payload: tuple) -> None:
        """A stereo frame, for the ``vision`` start's odometry until the start is decided."""
        if self.odometry is not None:
            self.odometry.add_frame(t_ns, payload)

    def add_gps(self, t_ns: int, p_W_G: np.ndarray, v_W_G: np.ndarray | None,
                off: bool = False) -> None:  # fmt: skip
        """A fix (``v_W_G`` None: position only). Two fixes with velocity start in flight;
        position-only fixes need a third (``init._from_gps`` differences them). ``off``: the
        run fuses no GPS at its time (an outage): the ``vision`` start does not take it."""
        fix = (t_ns, p_W_G, np.full(3, np.nan) if v_W_G is None or not self._gps_velocity
               else v_W_G)  # fmt: skip
        if self.options.mode != "gps":
            if len(self._gps) < 2:
                self._gps.append(fix)
        else:
            # every fix until the start: those after a complete selection start the next pair
            # when the selection is refused (they were dropped, and a run fed its fixes ahead of
            # the IMU never started: a review)
            self._gps.append(fix)
            if not self._picked[1]:
                self._picked = self._start_fixes()
        if self.odometry is not None and not off:
            recent = self._gps_recent
            recent.append(fix)
            # by time, not count: at 20 Hz the last 8 fixes missed the window's first frame
            # (a review); the odometry's window and the span around its first frame
            keep_ns = int(self.options.vision_window_s * 1e9) + 2 * GPS_START_SPAN_NS
            while recent and recent[0][0] < t_ns - keep_ns:
                recent.popleft()

    def _gps_at(self, t_ns: int, speed_mps: float) -> tuple[np.ndarray, float, str] | None:
        """The GPS antenna's position (3,) m at ``t_ns``, its standard deviation (m) and how it
        was had (for the report): the fix with a velocity nearest in time, within
        ``GPS_START_SPAN_NS``, carried to ``t_ns`` by that velocity; without one, position-only
        fixes: the two either side (else the two nearest) inter- or extrapolated, off by the
        path's bend at ``GPS_INTERP_ACCEL_MPS2`` (the nearest alone was 1.14 m off for 0.13 s
        at 8.5 m/s: KITTI raw from 14 s); one alone, uncertain by the distance the start's
        ``speed_mps`` covers to it (its direction is the heading sought); None without any."""
        gps = self.rig.gps
        near = [(abs(t - t_ns), t, p, v) for t, p, v in self._gps_recent
                if abs(t - t_ns) <= GPS_START_SPAN_NS]  # fmt: skip
        with_v = [n for n in near if np.all(np.isfinite(n[3]))]
        if gps is None or not near:
            return None
        if with_v:
            _, t, p, v = min(with_v, key=lambda n: n[0])
            dt_s = (t_ns - t) * 1e-9
            return (np.asarray(p, float) + dt_s * np.asarray(v, float),
                    float(np.hypot(gps.position_noise_std, abs(dt_s) * gps.velocity_noise_std)),
                    "the nearest GPS fix")  # fmt: skip
        _, t, p, _ = min(near, key=lambda n: n[0])
        best = (np.asarray(p, float),
                float(np.hypot(gps.position_noise_std, abs(t_ns - t) * 1e-9 * speed_mps)),
                "the nearest GPS fix (position only)")
        before = sorted((n for n in near if n[1] <= t_ns), key=lambda n: n[0])
        after = sorted((n for n in near if n[1] > t_ns), key=lambda n: n[0])
        # the two fixes either side, else the two nearest on one side (a run that starts
        # between fixes has none before)
        pair = before[:1] + after[:1] if before and after else (before or after)[:2]
        if len(pair) < 2 or pair[0][1] == pair[1][1]:
            return best
        (_, ta, pa, _), (_, tb, pb, _) = sorted(pair, key=lambda n: n[1])
        w = (t_ns - ta) / (tb - ta)
        # the fixes' noise carried by the weights, and a quadratic path's departure from the
        # chord (``|p''| / 2 · |t - ta| |t - tb|``); far outside the pair the nearest fix
        # alone is surer (w = -38 gave 77 m against 15 m: a review)
        bend = 0.5 * GPS_INTERP_ACCEL_MPS2 * abs(t_ns - ta) * abs(t_ns - tb) * 1e-18
        std = float(np.hypot(gps.position_noise_std * np.hypot(1.0 - w, w), bend))
        if std >= best[1]:
            return best
        how = "interpolated" if 0.0 <= w <= 1.0 else "extrapolated"
        return ((1.0 - w) * np.asarray(pa, float) + w * np.asarray(pb, float), std,
                f"two position-only GPS fixes, {how}")

    def _gps_arrays(self) -> GpsArrays | None:
        if not self._gps:
            return None
        t, p, v = zip(*self._gps, strict=True)
        return GpsArrays(np.array(t, np.int64), np.array(p, float), np.array(v, float))

    def _start_fixes(self) -> tuple[GpsArrays | None, bool]:
        """The ``gps`` start's fixes so far (``init.start_fixes``) and whether they suffice."""
        gps = self._gps_arrays()
        if gps is None or self.rig.gps is None:
            return None, False
        return start_fixes(gps, self.rig.gps.velocity_noise_std)

    def _data(self, history: ImuHistory) -> InitData:
        # The history is already in the body frame: no IMU mount to apply again.
        mag = gps = None
        if self._mag:
            t, m = zip(*self._mag, strict=True)
            mag = MagArrays(np.array(t, np.int64), np.array(m, float))
        gps = self._gps_arrays()
        return InitData(
            "navigator", self.rig.gravity_W,
            ImuArrays(history.t_ns.copy(), history.gyro_B.copy(), history.accel_B.copy()),
            None, mag, self.rig.mag, gps, self.rig.gps, gps_fused=self.gps_fused,
            local_heading_wait=self.local_heading_wait,
        )  # fmt: skip

    def try_start(self, history: ImuHistory, horizon_ns: int | None) -> InitialState | None:
        """The initial state once the data it needs has arrived (``horizon_ns``: every
        measurement stamped before it has been released), else None; raises
        ``InitialisationError`` when the data cannot give one."""
        last = history.last_ns
        if last is None or horizon_ns is None:
            return None
        if self.given is not None:
            return given_at_sample(self.given, history.t_ns) if last >= self.given.t_ns else None
        o = self.options
        if o.mode == "vision":
            return self._vision_start(history, horizon_ns)
        if o.mode == "gps":
            fixes, complete = self._picked
            if fixes is None or not complete or horizon_ns <= fixes.t_ns[-1]:
                return None
            try:
                return initialise(self._data(history), self.layout, o)
            except StartFixesRefusedError as exc:
                # a glitch in one fix: the next pair starts it, up to a few times
                self._refused.append(str(exc))
                if len(self._refused) >= MAX_REFUSED_START_FIXES:
                    raise InitialisationError(
                        f"{len(self._refused)} pairs of GPS fixes in a row disagree with the "
                        f"accelerometer or each other (the last: {self._refused[-1]})"
                    ) from exc  # fmt: skip
                log.warning("the in-flight start waits for the next GPS fix: %s", exc)
                # the next pair starts at the refused pair's second fix
                self._gps = [f for f in self._gps if f[0] >= fixes.t_ns[1]]
                self._picked = self._start_fixes()
                return None
        if history.n < 3:
            return None
        t_first, t0 = int(history.t_ns[0]), int(history.t_ns[2])
        static_ns = int(o.static_s * 1e9)
        if last <= t_first + static_ns:
            return None
        if self.rig.mag is not None and horizon_ns <= t0 + static_ns:
            return None
        # A run that fuses no GPS neither waits for a fix nor takes its position from one: a
        # fix's metre of noise as the start's position spread the sigma points of a
        # GPS-denied run (rendered keyframes: 0.17 -> 0.71 m; a user's probe).
        uses_gps = self.rig.gps is not None and self.gps_fused is not False
        wait_ns = static_ns + int(o.gps_wait_s * 1e9)
        if uses_gps and not self._gps and horizon_ns <= t_first + wait_ns:
            return None
        data = self._data(history)
        if not uses_gps:
            data = replace(data, gps=None)
        return initialise(data, self.layout, o)

    def waiting_for(self, history: ImuHistory) -> str:
        """What the start still lacked when the stream ended (one clause, for the error)."""
        o = self.options
        got = 0.0 if history.n == 0 else (history.last_ns - int(history.t_ns[0])) * 1e-9
        if self.given is not None:
            return (f"the given initial state is stamped {self.given.t_ns} ns, after the last "
                    f"IMU sample")  # fmt: skip
        if o.mode == "gps":
            return ("init.mode gps needs 2 GPS fixes with velocities (3 positions only) "
                    f"spaced for their noise (init.start_fixes), the stream had {len(self._gps)}"
                    f" over {got:.2f} s of IMU")
        return (f"the static start needs more than init.static_s = {o.static_s:g} s of IMU "
                f"samples, the stream had {got:.2f} s")  # fmt: skip

    def _vision_start(self, history: ImuHistory, horizon_ns: int) -> InitialState | None:
        """Once the odometry spans ``init.vision_window_s`` in one chain and the IMU covers it:
        the fit (``navigation.vision_start``) at the first IMU sample from its first frame."""
        odo = self.odometry
        o = self.options
        assert odo is not None
        last = history.last_ns
        if (len(odo.t_ns) < 4 or odo.span_s() < o.vision_window_s or last is None
                or last < odo.t_ns[-1] or horizon_ns <= odo.t_ns[-1]):  # fmt: skip
            return None
        t_f, R_V_B, p_V_B = odo.body_poses()
        t_imu, gyro_B, accel_B = history.t_ns, history.gyro_B, history.accel_B
        cal = self.rig.imu
        g_W = np.asarray(self.rig.gravity_W, float)
        fit = fit_vision_inertial(
            t_f, R_V_B, p_V_B, t_imu, gyro_B, accel_B, g_W, o.vision_max_g_error,
            0.0 if cal is None else cal.gyro_noise_density, o.gyro_bias_std,
            0.0 if cal is None else cal.accel_noise_density,
        )  # fmt: skip
        if fit.span_s > SPARSE_START_FACTOR * o.vision_window_s:
            log.warning("the in-flight start from vision fitted %d frames over %.1f s "
                        "(init.vision_window_s %g): with frames this far apart the IMU carries "
                        "the fit, and its biases beyond init.accel_bias_std and "
                        "init.gyro_bias_std can leave the filter overconfident; a static start, "
                        "--init groundtruth or GPS is surer", fit.frames, fit.span_s,
                        o.vision_window_s)  # fmt: skip
        k = int(np.searchsorted(t_imu, fit.t0_ns))
        t_s = int(t_imu[k])
        R_W_B, v_W_B = state_at(fit, R_V_B[0], t_imu, gyro_B, accel_B, t_s)
        gps_fused = bool(self.gps_fused if self.gps_fused is not None else self.rig.gps)
        m_B = m_W = None
        if self.rig.mag is not None:  # the heading, as a static start takes it
            near = [m for t, m in self._mag if abs(t - t_s) <= MAG_HEADING_SPAN_NS]
            if near:
                m_B = self.rig.mag.T_B_S[:3, :3] @ np.mean(near, axis=0)
                m_W = self.rig.mag.m_W
        self.odometry = None  # its frames and front end are no longer needed
        gps_fix = (self._gps_at(t_s, float(np.linalg.norm(v_W_B)))
                   if gps_fused and self.rig.gps is not None else None)  # fmt: skip
        p_B_G = None if self.rig.gps is None else self.rig.gps.p_B_G
        return from_vision_fit(fit, t_s, R_W_B, v_W_B, gyro_B[k] - fit.b_g, self.layout, o,
                               g_W, gps_fused, m_B, m_W, gps_fix, p_B_G)  # fmt: skip
