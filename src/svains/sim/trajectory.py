"""Smooth body trajectories with exact derivatives: a uniform cubic B-spline on R³ × SO(3).

Position is an ordinary cubic B-spline; attitude is a *cumulative* cubic B-spline on SO(3)
(``R(t) = R_i Π_j Exp(λ_j(u) d_j)``, ``d_j = Log(R_{i+j-1}^T R_{i+j})``), so the body rate
``omega_B``, angular acceleration ``alpha_B``, velocity and acceleration are the spline's own
analytic derivatives: a strapdown integration of ``(omega_B, f_B)`` reproduces the pose (the
tests check it). Both splines are C², so specific force and angular acceleration are continuous.

Control point ``k`` sits at time ``t0_s + (k - 1) dt_s``; the curve is defined on
``[t0_s, t0_s + (n - 3) dt_s]`` for ``n`` control points. Times are float seconds here; the
caller converts from int64 ns at the file edge.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.datasets.trajectory import read_tum as datasets_read_tum
from svains.errors import ConfigError, DatasetError
from svains.geometry.rotation import rotmat_to_quat, so3_exp, so3_log

F64 = NDArray[np.float64]

# Basis matrices: row = power of u (1, u, u², u³), column = control point offset 0..3.
_M = np.array([[1, 4, 1, 0], [-3, 0, 3, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], dtype=float) / 6.0
_M_CUM = np.array([[6, 5, 1, 0], [0, 3, 3, 0], [0, -3, 3, 0], [0, 1, -2, 1]], dtype=float) / 6.0


@dataclass(frozen=True)
class TrajectorySample:
    """True body kinematics at N times (world W, body B = IMU).

    ``p_W_B``, ``v_W_B``, ``a_W`` (N, 3) m, m/s, m/s²; ``R_W_B`` (N, 3, 3);
    ``omega_B`` (N, 3) rad/s and ``alpha_B`` (N, 3) rad/s² in body components.
    """

    p_W_B: F64
    v_W_B: F64
    a_W: F64
    R_W_B: F64
    omega_B: F64
    alpha_B: F64

    @property
    def q_W_B_wxyz(self) -> F64:
        return rotmat_to_quat(self.R_W_B)

    def specific_force_B(self, g_W: ArrayLike) -> F64:
        """``f_B = R_W_B^T (a_W - g_W)`` (N, 3) m/s²."""
        g = np.asarray(g_W, dtype=float)
        return np.einsum("nji,nj->ni", self.R_W_B, self.a_W - g)


def _powers(u: F64) -> tuple[F64, F64, F64]:
    """Rows (N, 4) of (1, u, u², u³) and their first and second u-derivatives."""
    one, zero = np.ones_like(u), np.zeros_like(u)
    p0 = np.stack([one, u, u * u, u**3], axis=1)
    p1 = np.stack([zero, one, 2 * u, 3 * u * u], axis=1)
    p2 = np.stack([zero, zero, 2 * one, 6 * u], axis=1)
    return p0, p1, p2


class SplineTrajectory:
    """Uniform cubic B-spline trajectory on R³ × SO(3).

    ``p_ctrl`` (n, 3) m and ``R_ctrl`` (n, 3, 3) control points, knot spacing ``dt_s``.
    """

    def __init__(self, t0_s: float, dt_s: float, p_ctrl: ArrayLike, R_ctrl: ArrayLike) -> None:
        self.p_ctrl = np.asarray(p_ctrl, dtype=float)
        self.R_ctrl = np.asarray(R_ctrl, dtype=float)
        n = len(self.p_ctrl)
        if n < 4 or self.R_ctrl.shape != (n, 3, 3) or self.p_ctrl.shape != (n, 3):
            raise ConfigError(f"spline needs >= 4 matching control points, got {n}")
        if not dt_s > 0:
            raise ConfigError(f"knot spacing must be positive, got {dt_s}")
        self.t0_s = float(t0_s)
        self.dt_s = float(dt_s)
        # d_k = Log(R_{k-1}^T R_k), k = 1..n-1 (row k-1)
        rel = np.einsum("nji,njk->nik", self.R_ctrl[:-1], self.R_ctrl[1:])
        self._d = so3_log(rel)

    @property
    def t_min(self) -> float:
        return self.t0_s

    @property
    def t_max(self) -> float:
        return self.t0_s + (len(self.p_ctrl) - 3) * self.dt_s

    def evaluate(self, t_s: ArrayLike) -> TrajectorySample:
        """Kinematics at times ``t_s`` (N,) s inside ``[t_min, t_max]``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        tol = 1e-9
        if t.size and (t.min() < self.t_min - tol or t.max() > self.t_max + tol):
            raise ConfigError(
                f"time outside the trajectory [{self.t_min:.3f}, {self.t_max:.3f}] s: "
                f"[{t.min():.3f}, {t.max():.3f}]"
            )
        x = (t - self.t0_s) / self.dt_s
        i = np.clip(np.floor(x).astype(int), 0, len(self.p_ctrl) - 4)
        u = x - i
        P0, P1, P2 = _powers(u)
        idx = i[:, None] + np.arange(4)[None, :]
        ctrl = self.p_ctrl[idx]  # (N, 4, 3)
        inv = 1.0 / self.dt_s
        p = np.einsum("nk,nkd->nd", P0 @ _M, ctrl)
        v = np.einsum("nk,nkd->nd", P1 @ _M, ctrl) * inv
        a = np.einsum("nk,nkd->nd", P2 @ _M, ctrl) * inv * inv

        lam, dlam, ddlam = P0 @ _M_CUM, P1 @ _M_CUM * inv, P2 @ _M_CUM * inv * inv
        R = self.R_ctrl[i].copy()
        omega = np.zeros((len(t), 3))
        alpha = np.zeros((len(t), 3))
        for j in (1, 2, 3):
            d = self._d[i + j - 1]  # Log(R_{i+j-1}^T R_{i+j})
            A = so3_exp(lam[:, j, None] * d)
            R = R @ A
            w_rel = dlam[:, j, None] * d
            # body rate of a product R^(j) = R^(j-1) A_j: ω^(j) = A_j^T ω^(j-1) + λ̇_j d_j, and
            # its derivative α^(j) = A_j^T α^(j-1) + λ̈_j d_j + ω^(j) × λ̇_j d_j.
            omega = np.einsum("nji,nj->ni", A, omega) + w_rel
            alpha = (
                np.einsum("nji,nj->ni", A, alpha)
                + ddlam[:, j, None] * d
                + np.cross(omega, w_rel)
            )
        return TrajectorySample(p, v, a, R, omega, alpha)


def _rpy_to_rotmat(roll: F64, pitch: F64, yaw: F64) -> F64:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (N, 3, 3)."""
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    R = np.empty((len(roll), 3, 3))
    R[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], 1)
    R[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], 1)
    R[:, 2] = np.stack([-sp, cp * sr, cp * cr], 1)
    return R


def rounded_rectangle(
    s: ArrayLike, size: tuple[float, float], radius: float
) -> tuple[F64, F64, F64]:
    """Point, heading (unwrapped, rad) and curvature (1/m) at arc length ``s`` (N,) m along a
    counter-clockwise rounded rectangle centred at the origin, starting at (0, -Ly/2) heading +x.
    """
    a, b = 0.5 * size[0], 0.5 * size[1]
    r = float(radius)
    if not (0 < r < min(a, b)):
        raise ConfigError(f"corner radius {r} must be in (0, {min(a, b)})")
    sx, sy, arc = 2 * (a - r), 2 * (b - r), 0.5 * np.pi * r
    perim = 2 * sx + 2 * sy + 4 * arc
    s = np.asarray(s, dtype=float)
    lap, sl = np.divmod(s - 0.0, perim)
    # segments: half bottom, arc, right, arc, top, arc, left, arc, half bottom
    lengths = np.array([sx / 2, arc, sy, arc, sx, arc, sy, arc, sx / 2])
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    seg = np.clip(np.searchsorted(starts, sl, side="right") - 1, 0, 8)
    ds = sl - starts[seg]
    # straight segment start points and headings; arc centres (corner k = 0..3)
    heading0 = np.array([0, 0, 0.5, 0.5, 1.0, 1.0, 1.5, 1.5, 2.0]) * np.pi
    p_start = np.array([[0, -b], [a - r, -b], [a, -b + r], [a, b - r], [a - r, b],
                        [-a + r, b], [-a, b - r], [-a, -b + r], [-a + r, -b]], dtype=float)
    centres = np.array([[a - r, -b + r], [a - r, b - r], [-a + r, b - r], [-a + r, -b + r]])
    is_arc = seg % 2 == 1
    h0 = heading0[seg]
    heading = h0 + np.where(is_arc, ds / r, 0.0)
    pt = p_start[seg] + ds[:, None] * np.stack([np.cos(h0), np.sin(h0)], 1)
    c = centres[np.clip((seg - 1) // 2, 0, 3)]
    ang = heading - 0.5 * np.pi  # direction from the arc centre to the point
    pt_arc = c + r * np.stack([np.cos(ang), np.sin(ang)], 1)
    pt = np.where(is_arc[:, None], pt_arc, pt)
    kappa = np.where(is_arc, 1.0 / r, 0.0)
    return pt, heading + 2 * np.pi * lap, kappa


def _smooth(x: F64, win: int) -> F64:
    """Centred moving average of (N, D) rows over ``win`` samples (edges: shrinking window)."""
    kernel = np.ones(win) / win
    out = np.empty_like(x)
    norm = np.convolve(np.ones(len(x)), kernel, mode="same")
    for k in range(x.shape[1]):
        out[:, k] = np.convolve(x[:, k], kernel, mode="same") / norm
    return out


def speed_profile(t_s: ArrayLike, stops: Sequence[Sequence[float]], ramp_s: float) -> F64:
    """The fraction (N,) of the cruise speed at times ``t_s`` (N,) s: 0 inside each stop
    ``(start_s, duration_s)``, easing down over the ``ramp_s`` before it and up over those
    after (half a cosine: no jump of acceleration at the ramp's ends), 1 elsewhere; a stop
    from 0 s or earlier holds from before the start (a static start); overlapping stops
    multiply (``SimConfig.validate`` refuses stops whose ramps overlap)."""
    t = np.asarray(t_s, dtype=float)
    f = np.ones_like(t)
    for start, dur in stops:
        a, b = float(start), float(start) + float(dur)
        # distance from the stop (<= 0 inside); one from 0 s is a rest since before the start
        d = t - b if a <= 0.0 else np.maximum(a - t, t - b)
        f *= np.where(d <= 0.0, 0.0,
                      0.5 * (1.0 - np.cos(np.pi * np.clip(d / ramp_s, 0.0, 1.0))))  # fmt: skip
    return f


def village_trajectory(
    duration_s: float,
    size: tuple[float, float],
    radius: float,
    altitude: float,
    speed: float,
    gravity: float = 9.81,
    bank: bool = True,
    vibration_deg: float = 0.3,
    vibration_hz: float = 3.0,
    knot_dt_s: float = 0.05,
    seed: int = 0,
    stops: Sequence[Sequence[float]] = (),
    stop_ramp_s: float = 2.0,
) -> SplineTrajectory:
    """The paper's flight: rounded rectangle at constant altitude and speed, body x forward,
    y left, z up; coordinated bank in turns, slight nose-down pitch and small vibration;
    at rest through each of ``stops`` (``(start_s, duration_s)``, eased over ``stop_ramp_s``:
    :func:`speed_profile`)."""
    n = int(np.ceil(duration_s / knot_dt_s)) + 4
    tau = (np.arange(n) - 1) * knot_dt_s
    # a margin of knots on both sides lets the smoothing below see past the ends
    pad = int(np.ceil(1.0 / knot_dt_s))
    tau_pad = (np.arange(-pad, n + pad) - 1) * knot_dt_s
    s_cruise = speed * tau_pad
    xy, yaw, kappa = rounded_rectangle(s_cruise, size, radius)
    # The rounded rectangle's curvature jumps at each arc; a helicopter eases into a turn, so
    # smooth path, heading and curvature (two passes of a ~0.5 s moving average at the cruise
    # speed) before use.
    win = max(1, round(0.5 / knot_dt_s))
    path = np.column_stack([_smooth(_smooth(xy, win), win),
                            _smooth(_smooth(np.column_stack([yaw, kappa]), win), win)])
    v_pad = speed * speed_profile(tau_pad, stops, stop_ramp_s)
    if stops:
        # the smoothed path at the arc length travelled (0 at t = 0; trapezoids over the
        # knots): a stop holds one point of it, exactly
        s_pad = np.concatenate([[0.0], np.cumsum(0.5 * (v_pad[1:] + v_pad[:-1]) * knot_dt_s)])
        s_pad -= np.interp(0.0, tau_pad, s_pad)
        path = np.column_stack([np.interp(s_pad, s_cruise, c) for c in path.T])
    xy, yaw, kappa = path[pad:-pad, 0:2], path[pad:-pad, 2], path[pad:-pad, 3]
    p = np.column_stack([xy, np.full(n, altitude)])
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 3)
    vib = np.radians(vibration_deg) * np.sin(2 * np.pi * vibration_hz * tau[:, None] + ph)
    v = v_pad[pad:-pad]
    if stops:
        vib = vib * (v / speed)[:, None]  # the shaking fades with the speed: none at rest
    # left turn (kappa > 0) lifts the right side: negative roll about x (forward) with y left
    roll = -np.arctan(v**2 * kappa / gravity) if bank else np.zeros(n)
    pitch = np.full(n, np.radians(3.0))  # nose down to fly forward
    R = _rpy_to_rotmat(roll + vib[:, 0], pitch + vib[:, 1], yaw + 0.5 * vib[:, 2])
    return SplineTrajectory(0.0, knot_dt_s, p, R)


def read_tum(path: Path | str) -> tuple[F64, F64, F64]:
    """TUM file -> times (N,) s, positions (N, 3) m, quaternions (N, 4) wxyz (>= 8 rows).

    Parsing is ``svains.datasets.trajectory.read_tum``'s; this adds the spline's minimum length.
    """
    try:
        t_ns, p, q_wxyz = datasets_read_tum(path)
    except DatasetError as exc:
        raise DatasetError(f"cannot read TUM trajectory {path}: {exc}") from exc
    if len(t_ns) < 8:
        raise DatasetError(f"TUM trajectory {path}: need >= 8 rows of 't x y z qx qy qz qw'")
    return t_ns * 1e-9, p, q_wxyz


# What the simulator can fly: a car on a motorway, a village some kilometres across.
MAX_SPEED_M_S = 100.0
MAX_EXTENT_M = 10_000.0


def tum_trajectory(
    path: Path | str, duration_s: float | None = None, knot_dt_s: float = 0.05
) -> SplineTrajectory:
    """Spline through a TUM file's poses (control points = poses resampled at the knots, so the
    spline is a slightly smoothed copy of the file), shifted so it starts at t = 0."""
    from scipy.spatial.transform import Rotation, Slerp

    t, p, q = read_tum(path)
    t = t - t[0]
    span = t[-1] - 2 * knot_dt_s
    dur = span if duration_s is None else min(duration_s, span)
    if dur <= 0:
        raise DatasetError(f"TUM trajectory {path} is too short")
    n = int(np.ceil(dur / knot_dt_s)) + 3
    tau = knot_dt_s * np.arange(n)  # file time of control point k
    p_ctrl = np.column_stack([np.interp(tau, t, p[:, k]) for k in range(3)])
    # A file in millimetres flies a metre-sized path at kilometres per second, and the world
    # built around it asked for 76 GiB (a user's probe): refused before any work
    speed = float(np.max(np.linalg.norm(np.diff(p_ctrl, axis=0), axis=1))) / knot_dt_s
    extent = float(np.max(np.ptp(p_ctrl, axis=0)))
    if speed > MAX_SPEED_M_S or extent > MAX_EXTENT_M:
        raise DatasetError(
            f"TUM trajectory {path}: its poses move at up to {speed:.4g} m/s over {extent:.4g} m "
            f"(the simulator flies at most {MAX_SPEED_M_S:g} m/s over {MAX_EXTENT_M:g} m): "
            "positions in millimetres? TUM files hold metres")  # fmt: skip
    rot = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]]))
    R_ctrl = Slerp(t, rot)(np.clip(tau, t[0], t[-1])).as_matrix()
    # control point k sits at spline time (k - 1) dt, i.e. spline time t is file time t + dt
    return SplineTrajectory(0.0, knot_dt_s, p_ctrl, R_ctrl)
