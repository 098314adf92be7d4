"""A heading gone wrong, found from the GPS velocities and turned back.

A filter sure of a wrong heading (a magnetometer whose ``T_BS`` is off, a start heading taken
from a course the vehicle does not fly) integrates the IMU in a world turned by that error: its
velocity changes between two GPS fixes are the true ones turned about the vertical. GPS gates
then refuse the velocities, the consistency monitor reads the refusals as bias steps, multipath
or a lost filter, and none of its actions touches the heading (the simulator's village with
the magnetometer turned 90° and an in-flight start: `3d` 21.7 m off, GPS refused to the end).

:class:`HeadingCheck` compares, fix by fix, the filter's horizontal velocity change since the
previous fix (from its state after that fix to its prediction at this one: IMU and any vision
in between, no GPS) with the GPS's over the same interval. Over a window of such steps the
rotation about the vertical that best maps the first onto the second (least squares: the angle
of ``Σ p·g`` and ``Σ (p×g)·up``) is the heading error, with a standard deviation
``σΔ / √(Σ|g|²)`` (``σΔ`` the noise of one step's difference: both GPS fixes' velocity noise and
the accelerometer's white noise over the step). It is acted on only when the steps moved
enough to pin it (standard deviation at most ``max_std_deg``), it exceeds ``min_error_deg``,
four of its own standard deviations and four of the filter's yaw standard deviation, and the
turned steps fit the GPS ones within their noise (a chi-square test): a GPS velocity that jumps
or scatters is no rotation. The same fit runs on the filter's velocities themselves (a vision
method's, held to the camera's motion in the body frame) and, for a vision method, on the
camera's own velocities: each frame pair's egomotion turned into the filter's world by its
attitude at that frame, whether or not the filter fused the frame, against the GPS velocities
interpolated at the pair's middle. In straight flight the velocity changes are too small to
show a wrong heading and the frames are refused under it; the camera still shows it.
:func:`turn_heading` then turns the state about the vertical through the current position:
attitude, velocity, and every pose clone (rigidly, so the motion since each clone is
unchanged), with the turn's uncertainty added to the covariance; :func:`widen_position` lets a
position that the refused fixes did not hold follow the next one.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from itertools import chain
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.filter.manifold import Manifold
from svains.filter.ukf import UKF
from svains.geometry.rotation import quat_exp, quat_multiply, quat_normalize, quat_to_rotmat
from svains.models.clones import CloneManifold
from svains.models.state import DP, DTH, DV, Q, V
from svains.models.state import P as POS

F64 = NDArray[np.float64]


def horizontal_basis(up_W: F64) -> F64:
    """Two horizontal unit vectors (2, 3) with ``e1 × e2 = up`` for the unit vertical ``up_W``
    (3,): turns about the vertical turn their coordinates as x and y about z."""
    up = np.asarray(up_W, dtype=float)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1)])


def horizontal(v: F64, up_W: F64) -> F64:
    """``v`` (3,) without its part along the unit vertical ``up_W`` (3,)."""
    v = np.asarray(v, dtype=float)
    return v - (v @ up_W) * up_W


# At most this many fixes are kept to interpolate the GPS velocity at a frame pair's middle,
# those of the rows' span (``window`` x ``max_step_s``): 8 s of a 200 Hz receiver. By count
# alone (20) a 50 Hz GPS kept 0.4 s and a 1 Hz camera's pairs, 0.5 s back, were never heard
# (a review).
RECENT_FIXES = 1600


@dataclass(frozen=True)
class HeadingCheckOptions:
    """``window`` GPS steps (each at most ``max_step_s`` long) per estimate; a turn needs the
    estimate at most ``max_std_deg`` uncertain, at least ``min_error_deg``, and the turned steps
    within the noise at ``fit_probability``."""

    window: int = 4
    max_step_s: float = 2.0
    min_error_deg: float = 20.0
    max_std_deg: float = 10.0
    fit_probability: float = 0.999


@dataclass(frozen=True)
class HeadingError:
    """A heading error found: the filter's world is turned by ``-angle_rad`` about the vertical
    (turning it by ``angle_rad`` mends it), known to ``std_rad``, over ``steps`` GPS steps;
    ``witness``: whose vectors against the GPS's showed it."""

    angle_rad: float
    std_rad: float
    steps: int
    witness: str = "gps"  # the filter's velocities or their changes; "camera": the camera's

    def source(self) -> str:
        """What showed the error, in words."""
        return ("the camera's velocities against the GPS's" if self.witness == "camera"
                else "the GPS velocities")  # fmt: skip


class HeadingCheck:
    """Velocity changes between GPS fixes, filter against GPS (see the module docstring)."""

    def __init__(self, up_W: F64, velocity_noise_std: float, accel_noise_density: float,
                 options: HeadingCheckOptions | None = None) -> None:  # fmt: skip
        """``up_W`` (3,); the GPS's velocity noise (m/s) and the accelerometer's white-noise
        density (m/s²/√Hz) the filter uses."""
        up = np.asarray(up_W, dtype=float)
        self.up_W = up / np.linalg.norm(up)
        self.options = options or HeadingCheckOptions()
        self._var_v = float(velocity_noise_std) ** 2
        self._var_a = float(accel_noise_density) ** 2
        self._steps: deque[tuple[F64, F64, float]] = deque(maxlen=self.options.window)
        self._fixes: deque[tuple[F64, F64, float]] = deque(maxlen=self.options.window)
        # the camera's velocities (a vision method's egomotion, turned by the filter's
        # attitude) against the GPS's, and the time of each (ns)
        self._vision: deque[tuple[F64, F64, float, int]] = deque(maxlen=self.options.window)
        self._prev: tuple[int, F64, F64] | None = None  # t_ns, filter v after, GPS v
        # the fixes before it (t_ns, GPS v), to interpolate at a frame pair's middle
        self._recent: deque[tuple[int, F64]] = deque(maxlen=RECENT_FIXES)
        self.turns: list[dict[str, float | bool | str]] = []

    def _horizontal(self, v: F64) -> F64:
        return horizontal(v, self.up_W)

    def restart(self) -> None:
        """Forget the velocities and steps kept (the frame they were compared in has turned)."""
        self._steps.clear()
        self._fixes.clear()
        self._vision.clear()
        self._prev = None
        self._recent.clear()

    def before_update(self, t_ns: int, v_pred_W: F64, v_gps_W: F64, yaw_std_rad: float,
                      v_var: float = 0.0, usable: bool = True, acquire: bool = False,
                      vision: tuple[int, F64, float] | None = None,
                      ) -> HeadingError | None:  # fmt: skip
        """At a GPS fix, before its update: the filter's predicted velocity ``v_pred_W`` (3,)
        and its variance per axis ``v_var`` (m²/s²), the fix's ``v_gps_W`` (3,) m/s, the
        filter's yaw standard deviation. ``usable`` False: the interval since the previous fix
        or this fix's velocity cannot be compared (an IMU gap bridged in it, a GPS velocity the
        recovery switched off): the windows start again. ``acquire``: the filter runs in a
        local frame whose heading is sought (a start with neither magnetometer nor course):
        any sure and fitting estimate is returned, however small. ``vision``: a time (ns)
        between a recent fix (``RECENT_FIXES``) and this one, the antenna's velocity (3,) m/s
        the camera measured there in the filter's world (turned by its attitude, so by its
        heading error) and its variance per axis (m²/s²), compared with the velocities of the
        two fixes around that time interpolated there (``_gps_at``); None: no such
        measurement. A heading error to mend now, or None."""
        o = self.options
        v_pred, v_gps = np.asarray(v_pred_W, float), np.asarray(v_gps_W, float)
        prev = self._prev
        if not usable or prev is None or (t_ns - prev[0]) * 1e-9 > o.max_step_s:
            self._steps.clear()
            if not acquire or not usable:
                # (the velocities themselves do not need short steps: a GPS below 0.5 Hz gave
                # a local start no heading at all, a user's probe)
                self._fixes.clear()
            if not usable:
                self._vision.clear()
                return None
        else:
            dt = (t_ns - prev[0]) * 1e-9
            self._steps.append((self._horizontal(v_pred - prev[1]),
                                self._horizontal(v_gps - prev[2]),
                                2.0 * self._var_v + self._var_a * dt))  # fmt: skip
        self._fixes.append((self._horizontal(v_pred), self._horizontal(v_gps),
                            self._var_v + float(v_var)))  # fmt: skip
        heard = False
        at = None if vision is None or acquire else self._gps_at(vision[0], t_ns, v_gps)
        if acquire:
            self._vision.clear()
        elif at is not None and vision is not None:
            g, factor = at
            self._vision.append((self._horizontal(vision[1]), self._horizontal(g),
                                 factor * self._var_v + float(vision[2]), int(vision[0])))
            heard = True
        # Fixes without a usable frame pair keep the rows (a GPS faster than the camera: at
        # 5-10 Hz against 1-2 Hz frames the rows were cleared at every fix and the camera never
        # heard, a review), as long as they are recent; so do the fixes.
        oldest = t_ns - int(o.window * o.max_step_s * 1e9)
        while self._vision and self._vision[0][3] < oldest:
            self._vision.popleft()
        while self._recent and self._recent[0][0] < oldest:
            self._recent.popleft()
        # Velocities (a vision method's, held to the camera's motion in the body frame, turn
        # with the heading) and velocity changes (the IMU's, which turn with it too). The GPS
        # velocity must disagree now too: a filter that has come round mends itself.
        found: list[HeadingError] = []
        if acquire or self._disagrees(self._fixes[-1]):
            tests = (self._rotation(self._fixes, yaw_std_rad, acquire),
                     self._rotation(self._steps, yaw_std_rad, acquire))
            found = [e for e in tests if e is not None]
        # The camera's own velocities, whether or not the filter fused its frames: a wrong
        # heading has its frames refused, and in straight flight the velocity changes are too
        # small to show it (simulated village, magnetometer turned 90°, seeds 2 and 6: never
        # turned). The camera must disagree now too.
        if heard and self._disagrees(self._vision[-1]):
            seen = self._rotation(self._vision, yaw_std_rad)
            if seen is not None:
                found.append(replace(seen, witness="camera"))
        if not found:
            return None
        error = min(found, key=lambda e: e.std_rad)
        self._steps.clear()
        self._fixes.clear()
        self._vision.clear()
        self.turns.append({"t_ns": float(t_ns), "angle_deg": math.degrees(error.angle_rad),
                           "std_deg": math.degrees(error.std_rad), "wait": acquire,
                           "witness": error.witness})  # fmt: skip
        return error

    def _gps_at(self, t: int, t_ns: int, v_gps: F64) -> tuple[F64, float] | None:
        """The GPS velocity (3,) at ``t`` (ns) interpolated between the two fixes around it (of
        this one at ``t_ns`` and the recent ones) and the factor of one fix's variance it
        carries; None when ``t`` lies outside them or the step is too long. A frame pair can
        end a fix or more back: with the camera at the GPS's stamps (the fix handled first) at
        the previous one, with a GPS faster than the camera several (a review: 1 Hz frames and
        fixes, the camera never heard)."""
        prev = self._prev
        if prev is None or (t_ns - prev[0]) * 1e-9 > self.options.max_step_s:
            return None
        tb, vb = t_ns, v_gps
        # newest first, and no further once past ``t`` (a pair's middle is rarely far back)
        for ta, va in chain(((prev[0], prev[2]),), reversed(self._recent)):
            if t > tb:
                return None
            if ta <= t:
                if (tb - ta) * 1e-9 > self.options.max_step_s:
                    return None
                w = (t - ta) / max(tb - ta, 1)
                return (1.0 - w) * va + w * vb, (1.0 - w) ** 2 + w**2
            tb, vb = ta, va
        return None

    def _disagrees(self, row: tuple[Any, ...]) -> bool:
        """Whether a row's filter vector and GPS vector (its first two) differ beyond their
        noise (its third)."""
        d = row[1] - row[0]
        return float(d @ d) / row[2] > chi2.ppf(self.options.fit_probability, 2)

    def _rotation(self, rows: deque[Any], yaw_std_rad: float,
                  acquire: bool = False) -> HeadingError | None:  # fmt: skip
        """The turn about the vertical mapping the filter's vectors of ``rows`` onto the GPS's,
        when the window is full and the turn is sure, large and fits (module docstring)."""
        o = self.options
        if len(rows) < o.window:
            return None
        ps = np.array([r[0] for r in rows])
        gs = np.array([r[1] for r in rows])
        var = np.array([r[2] for r in rows])
        energy = float(np.sum(gs * gs))
        if energy <= 0.0:
            return None
        angle = math.atan2(float(np.sum(np.cross(ps, gs) @ self.up_W)), float(np.sum(ps * gs)))
        c, s = math.cos(angle), math.sin(angle)
        turned = c * ps + s * np.cross(self.up_W, ps)  # Rodrigues about up (ps ⟂ up)
        fit = float(np.sum(np.sum((turned - gs) ** 2, axis=1) / var))
        if fit > chi2.ppf(o.fit_probability, 2 * len(ps)):
            return None
        # the rows' scatter about the turn, where it exceeds their stated noise, widens the
        # turn's spread: a GPS velocity three times noisier than declared turned right headings
        # 150-173° on the few windows whose fit passed (a review)
        scatter = max(1.0, fit / (2 * len(ps) - 1))
        std = math.sqrt(scatter * float(np.mean(var)) / energy)
        if std > math.radians(o.max_std_deg):
            return None
        if not acquire and abs(angle) < max(math.radians(o.min_error_deg), 4.0 * std,
                                            4.0 * yaw_std_rad):  # fmt: skip
            return None
        return HeadingError(angle, std, len(ps))

    @property
    def last_fix_ns(self) -> int:
        """The previous fix's time (-1 before any)."""
        return -1 if self._prev is None else self._prev[0]

    def after_update(self, t_ns: int, v_post_W: F64, v_gps_W: F64) -> None:
        """After the fix's update (accepted or not): the filter's velocity ``v_post_W`` (3,)."""
        if self._prev is not None:
            self._recent.append((self._prev[0], self._prev[2]))
        self._prev = (int(t_ns), np.array(v_post_W, float), np.array(v_gps_W, float))

    def summary(self) -> dict[str, object]:
        """The turns made: ``t_ns``, ``angle_deg``, ``std_deg`` each, ``wait``: the one
        that ended a start's heading wait (``init.heading_found_s``), and ``witness``: "gps"
        (the filter's velocities or their changes against the GPS's) or "camera" (the camera's
        velocities against the GPS's)."""
        return {"turns": [dict(t) for t in self.turns]}


def yaw_std(ukf: UKF, up_W: F64) -> float:
    """The filter's standard deviation (rad) of its heading: the attitude error (body frame)
    along the vertical."""
    u_B = quat_to_rotmat(ukf.x[Q]).T @ up_W
    return math.sqrt(max(float(u_B @ ukf.P[DTH, DTH] @ u_B), 0.0))


def turn_heading(ukf: UKF, error: HeadingError, up_W: F64, v_W: F64 | None = None,
                 v_std: float = 0.0, pivot_W: F64 | None = None) -> None:  # fmt: skip
    """Turn the state by ``error.angle_rad`` about ``up_W`` through the current position:
    attitude and velocity, and each pose clone rigidly (its position about the current one, its
    attitude), so the motion since each clone stays as it was. The covariance follows the map
    (world-frame position and velocity errors turn; body-frame attitude errors do not) and gains
    the turn's own uncertainty ``error.std_rad``, common to every turned part. ``v_W`` (3,)
    m/s: the velocity is set to it instead, with ``v_std`` per axis and no correlation (an
    INS's velocity error, GPS-corrected since the start, is no rotation of its velocity).
    ``pivot_W`` (3,) m: turn the whole frame about this point instead, the current position
    too (a local frame whose origin is the start's position, ``Core``'s heading wait)."""
    up = np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)
    q_z = quat_exp(error.angle_rad * up)
    Rz = quat_to_rotmat(q_z)
    x = ukf.x.copy()
    n = ukf.P.shape[0]
    J = np.eye(n)
    x[V] = Rz @ x[V]
    x[Q] = quat_normalize(quat_multiply(q_z, x[Q]))
    J[DV, DV] = Rz
    if pivot_W is not None:
        pivot = np.asarray(pivot_W, dtype=float)
        x[POS] = pivot + Rz @ (x[POS] - pivot)
        J[DP, DP] = Rz
    manifold = ukf.manifold
    if isinstance(manifold, CloneManifold):
        p = x[POS].copy() if pivot_W is None else np.asarray(pivot_W, dtype=float)
        for i in range(manifold.n_clones):
            cp, cq = manifold.columns(i)
            x[cp] = p + Rz @ (x[cp] - p)
            x[cq] = quat_normalize(quat_multiply(q_z, x[cq]))
            t = manifold.tangent(i)
            tp = slice(t.start, t.start + 3)
            J[tp, tp] = Rz
            if pivot_W is None:  # turned about the current position, which they follow
                J[tp, DP] = np.eye(3) - Rz
    a = turn_sensitivity(x, manifold, up, pivot_W)
    P = J @ ukf.P @ J.T + error.std_rad**2 * np.outer(a, a)
    transform: F64 | None = J
    if v_W is not None:
        x[V] = v_W
        P[DV, :] = 0.0
        P[:, DV] = 0.0
        P[DV, DV] = v_std**2 * np.eye(3)
        transform = None  # (the velocity replaced: no map of the old one, a smoother cuts)
    # a linear map of the tangent plus the turn's noise: a smoother's chain goes on through it
    # (written over the state, it was cut there, and the seconds of a heading wait before it
    # kept their forward error: 0.93 m smoothed against 0.05 m with a magnetometer, a probe)
    ukf.resize(ukf.manifold, x, P, transform)


def widen_position(ukf: UKF, offset_W: F64) -> None:
    """Add ``outer(offset_W, offset_W)`` (m²) to the covariance of the current position and of
    every pose clone's, as one common translation: the motion since each clone stays as sure
    as it was, the position as unsure as ``offset_W`` (3,) m, the distance to a fix that the
    state, dead-reckoned under a wrong heading, could not be trusted to be near."""
    d = np.asarray(offset_W, dtype=float)
    T = np.zeros((ukf.P.shape[0], 3))
    T[DP] = np.eye(3)
    manifold = ukf.manifold
    if isinstance(manifold, CloneManifold):
        for i in range(manifold.n_clones):
            t = manifold.tangent(i)
            T[t.start:t.start + 3] = np.eye(3)
    u = T @ d
    ukf.P = ukf.P + np.outer(u, u)


def turn_sensitivity(x: F64, manifold: Manifold, up_W: F64, pivot_W: F64 | None = None) -> F64:
    """How the state ``x`` (nx,), just turned about the unit vertical ``up_W`` (3,), moves with
    the turn's angle: d(state)/d(angle) (ndx,) in the tangent of ``manifold``, where a turn's
    uncertainty goes (``turn_heading``). Velocity and attitude turn; the position and the pose
    clones' positions turn about ``pivot_W`` (3,) m, or without one the clones about the
    current position, which stays."""
    up = np.asarray(up_W, dtype=float)
    a = np.zeros(manifold.ndx)
    a[DV] = np.cross(up, x[V])
    a[DTH] = quat_to_rotmat(x[Q]).T @ up
    p = np.asarray(x[POS], dtype=float)
    if pivot_W is not None:
        p = np.asarray(pivot_W, dtype=float)
        a[DP] = np.cross(up, x[POS] - p)
    if isinstance(manifold, CloneManifold):
        for i in range(manifold.n_clones):
            cp, cq = manifold.columns(i)
            t = manifold.tangent(i)
            a[t.start : t.start + 3] = np.cross(up, x[cp] - p)
            a[t.start + 3 : t.start + 6] = quat_to_rotmat(x[cq]).T @ up
    return a
