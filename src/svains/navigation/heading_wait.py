"""A start without a heading source, held in a local frame until GPS gives the heading.

With GPS fused and no magnetometer, the static start used to take an arbitrary heading with a
standard deviation of 28.6° (``init.yaw_std_unknown``). The true error can be anything up to
180°, which no UKF carries: the start's zero-velocity updates on a drone drifting at rest and
the first fixes while moving pulled the wrong heading in (σ 28.6° → 7.5° in 4 s with the error
at 163°), and the run stayed overconfident (a user's probe: NEES 1650 over a 40 s flight).

Instead (``init.heading_from_gps``) the start's heading defines a local frame, as without GPS
(its yaw error zero by construction), about the start's position. A fix that shows the vehicle
standing (horizontal speed within 3σ of the GPS's velocity noise) is fused and the frame's
pivot follows it; fixes that show it moving wait. ``HeadingCheck`` in its acquire mode compares
their velocities with the filter's, and once the rotation between the two frames is known to
its ``max_std_deg`` the state is turned into the world about the pivot with that uncertainty
(``turn_heading`` with ``pivot_W``), and so is everything kept in the local frame so far: the
logged estimates (``turn_logged``) and the stored keyframes. The fixes held meanwhile, each
carried to now along the filter's turned path, place the state (``carried_to_now``: one
horizontal update), and fixes are fused from then on.
Position-only fixes (or velocities not fused) give the heading from their path instead
(``FixPathHeading``; standing is then the antenna's own motion since the wait began within
half a fix's σ). Should no heading come within ``HEADING_WAIT_MAX_S`` worth of held fixes at
the GPS's rate (a slow vehicle, velocities that never fit one rotation), the path's turn is
taken if it is surer than an arbitrary heading, else the old start: the state and the logged
estimates turned by 0° with the uncertainty ``yaw_std_unknown`` about the pivot (their yaw,
and their positions by their distance from it) and the fixes fused, warned. The pivot is the
GPS antenna, where the local frame and the world agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.geometry.rotation import quat_exp, quat_multiply, quat_normalize, quat_to_rotmat
from svains.navigation.heading_check import HeadingError, horizontal_basis
from svains.navigation.outputs import FrameTurn

F64 = NDArray[np.float64]

# The longest wait (s) for the heading after the vehicle set off (30 s of fixes held cost a
# slow robot or a 0.2 Hz GPS 3-4 m: a user's probe).
HEADING_WAIT_MAX_S = 10.0


class FixPathHeading:
    """The heading for the wait from position-only fixes (a ROS ``NavSatFix`` carries no
    velocity): the rotation about the vertical that best maps the filter's own antenna path at
    the fixes (the local frame's) onto the fixes (the world's), translation free (a 2-D
    Procrustes fit of the centred horizontal paths, each point weighted by the inverse of its
    variance: the fix's ``σ_p²`` plus the filter's position variance gained since the least
    it had). Its variance is one over the weighted spread about the centroid: a long path pins
    it where one fix's difference (``√2 σ_p / Δt``) cannot (a drone at 1 m/s with 1.4 m fixes
    at 1 Hz). The fixes taken while standing count as one point at their mean, of one fix's
    variance (GPS errors last minutes: 200 of them drowned the fit test and shrank the
    standard deviation, and a jumped fix passed, 4.4σ off: a review). Taken once it is known
    to ``max_std_rad`` and the turned path fits the fixes (chi-square at ``fit_probability``,
    over the sum and, its level shared among them, over each point), the worst-fitting point
    left out, up to one in five (one multipath fix refused every later fit: a user's probe).
    Without it a start with no magnetometer took an arbitrary heading the first fixes
    collapsed (KITTI raw from 14 s, position-only: 117 m off at the end, the fixes refused as
    multipath: a user's probe)."""

    def __init__(self, up_W: F64, position_noise_std: float, max_std_rad: float,
                 fit_probability: float) -> None:  # fmt: skip
        # a horizontal basis: the fit is in its coordinates, the turn about ``up``
        self._E = horizontal_basis(np.asarray(up_W, dtype=float) / np.linalg.norm(up_W))
        self._var_p = float(position_noise_std) ** 2
        self._max_std = float(max_std_rad)
        self._fit_probability = float(fit_probability)
        self._gps_H: list[F64] = []  # the fixes in the horizontal basis (2,) m
        self._filter_H: list[F64] = []  # the filter's own path there (2,) m
        self._var: list[float] = []  # the filter's position variance at each (m²)
        self._t_ns: list[int] = []  # each point's time
        # the standing fixes: their sums (fix, filter) and count, and the least variance
        self._standing_H = np.zeros(4)
        self._standing_n = 0
        self._standing_var = math.inf
        self.last_ns = -1  # the latest point's time

    def clear(self) -> None:
        """Start the path again (an IMU fault bridged: the filter's path is broken; the wait
        over: nothing more to fit)."""
        self._gps_H.clear()
        self._filter_H.clear()
        self._var.clear()
        self._t_ns.clear()
        self._standing_H[:] = 0.0
        self._standing_n = 0
        self._standing_var = math.inf

    def add(self, t_ns: int, p_W_G: F64, p_W_A: F64, var_A: float, standing: bool = False,
            fit: bool = True) -> HeadingError | None:  # fmt: skip
        """A fix ``p_W_G`` (3,) m with the filter's own antenna path at it ``p_W_A`` (3,) m
        and its position variance per axis ``var_A`` (m²); ``standing``: the vehicle stood
        (the fix joins the standing mean). The heading error once known and fitting (the
        local frame turned by ``-angle_rad`` from the world), else None; ``fit`` False:
        stored only (``estimate`` later)."""
        self.last_ns = int(t_ns)
        g, f = self._E @ np.asarray(p_W_G, float), self._E @ np.asarray(p_W_A, float)
        if standing:
            self._standing_H += np.concatenate([g, f])
            self._standing_n += 1
            self._standing_var = min(self._standing_var, float(var_A))
        else:
            self._gps_H.append(g)
            self._filter_H.append(f)
            self._var.append(float(var_A))
            self._t_ns.append(int(t_ns))
        return self.estimate(self._max_std) if fit else None

    def _points(self) -> tuple[F64, F64, F64]:
        """The fixes (n, 2), the filter's path (n, 2) and their variances (n,): the standing
        mean first."""
        g, f, var = list(self._gps_H), list(self._filter_H), list(self._var)
        if self._standing_n:
            mean = self._standing_H / self._standing_n
            g, f, var = [mean[:2], *g], [mean[2:], *f], [self._standing_var, *var]
        v = np.asarray(var, dtype=float)
        gained = np.maximum(v - np.minimum.accumulate(v), 0.0) if v.size else v
        return np.array(g).reshape(-1, 2), np.array(f).reshape(-1, 2), self._var_p + gained

    def estimate(self, max_std_rad: float) -> HeadingError | None:
        """The path's heading error if known to ``max_std_rad`` and fitting, else None (at a
        wait's end a looser bound than ``add``'s beats an arbitrary heading)."""
        g_H, f_H, var = self._points()
        n = len(var)
        if n < 3:
            return None
        keep = np.ones(n, dtype=bool)
        for _ in range(n // 5 + 1):
            m = int(keep.sum())
            fitted = _turn_fit(g_H[keep], f_H[keep], 1.0 / var[keep])
            if fitted is None:
                return None
            angle, std, misfit = fitted
            if std > max_std_rad:
                return None
            p = self._fit_probability
            if (float(misfit.sum()) <= chi2.ppf(p, 2 * m - 3)
                    and float(misfit.max()) <= chi2.ppf(1.0 - (1.0 - p) / m, 2)):  # fmt: skip
                return HeadingError(angle, std, m)
            if m <= 3:
                return None
            keep[np.flatnonzero(keep)[int(np.argmax(misfit))]] = False
        return None

    @property
    def basis(self) -> F64:
        """The horizontal basis (2, 3) the path is kept in (``e1 × e2 = up``)."""
        return self._E

    def carried_to_now(self, angle_rad: float, own_L_A: F64,
                       before_ns: int) -> HeldFixes | None:  # fmt: skip
        """Where the fixes held while moving (taken before ``before_ns``; those while standing
        were fused) put the antenna now, the local frame turned by ``angle_rad`` into the
        world: each carried to now along the filter's own path, turned likewise (``own_L_A``
        (3,) m: that path's point now), their mean (``HeldFixes``); None without any that fit.
        A fix whose carried position is off their median beyond two fixes' noise (chi-square
        at ``fit_probability``) is left out. The mean's noise is one fix's, not the mean's (GPS
        errors last minutes: a few seconds of fixes are no surer than one). The path must be
        good: its error since each fix is the state's too, which no variance here holds (a
        vision method's; an INS's drifts: ``HeadingSteps._fuse_held_fixes``)."""
        sel = np.asarray(self._t_ns, dtype=np.int64) < before_ns
        if not sel.any():
            return None
        g_H = np.asarray(self._gps_H)[sel]
        f_H = np.asarray(self._filter_H)[sel]
        back = _turned(self._E @ np.asarray(own_L_A, float) - f_H, angle_rad)
        carried = g_H + back
        # about their median (a fix jumped 40 m dragged the mean of three past every test, and
        # all three were kept: a user's probe), each against another fix's noise as well
        centre = np.median(carried, axis=0)
        off = np.sum((carried - centre) ** 2, axis=1) / (2.0 * self._var_p)
        keep = off <= chi2.ppf(self._fit_probability, 2)
        if not keep.any():
            return None
        mean = carried[keep].mean(axis=0)
        # the turned path's derivative along the turn: up × b in the basis is (-b_y, b_x)
        d_turn = np.stack([-back[keep, 1], back[keep, 0]], axis=1).mean(axis=0)
        return HeldFixes(mean, self._var_p * np.eye(2), d_turn, int(keep.sum()))


@dataclass(frozen=True)
class HeldFixes:
    """The fixes a heading wait held, carried to now (``FixPathHeading.carried_to_now``): their
    mean ``z_H`` (2,) m in the path's ``basis``; its noise covariance ``R`` (2, 2) m²; how it
    moves with the turn's angle ``d_turn_H`` (2,) m/rad (for a turn too small by δψ the mean is
    off by ``-d_turn_H δψ``: the error it shares with the turned state); the fixes used ``n``."""

    z_H: F64
    R: F64
    d_turn_H: F64
    n: int


def _turn_fit(g_H: F64, f_H: F64, w: F64) -> tuple[float, float, F64] | None:
    """The weighted turn mapping the path ``f_H`` (m, 2) onto ``g_H`` (m, 2), both in a
    horizontal basis whose two axes turn about the vertical as x and y about z, translation
    free: its angle (rad), standard deviation (rad) and each point's weighted squared misfit
    (m,); None for a path with no spread."""
    g = g_H - w @ g_H / w.sum()
    f = f_H - w @ f_H / w.sum()
    spread = float(w @ np.sum(f * f, axis=1))
    if spread <= 0.0:
        return None
    angle = math.atan2(float(w @ (f[:, 0] * g[:, 1] - f[:, 1] * g[:, 0])),
                       float(w @ np.sum(f * g, axis=1)))  # fmt: skip
    turned = _turned(f, angle)
    return angle, math.sqrt(1.0 / spread), w * np.sum((turned - g) ** 2, axis=1)


def _turned(rows_H: F64, angle_rad: float) -> F64:
    """Each row (m, 2) of a horizontal basis whose axes turn about the vertical as x and y
    about z, turned by ``angle_rad``."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return rows_H @ np.array([[c, s], [-s, c]])


def turn_logged(
    log_x: list[F64], log_std: list[F64] | None, log_P9: list[F64] | None,
    error: HeadingError, up_W: F64, pivot_W: F64,
) -> None:
    """Turn logged estimates (in place) by ``error.angle_rad`` about the vertical ``up_W``
    through ``pivot_W`` (3,) m: position, velocity and attitude of each ``x`` (nx,), their
    ``P9`` (9, 9: p, v, δθ_B) by the map plus the turn's own uncertainty ``error.std_rad``, and
    the first nine tangent standard deviations of ``std`` from it (both None: the means
    alone)."""
    up = np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)
    pivot = np.asarray(pivot_W, dtype=float)
    q_z = quat_exp(error.angle_rad * up)
    Rz = quat_to_rotmat(q_z)
    J = np.eye(9)
    J[0:3, 0:3] = Rz
    J[3:6, 3:6] = Rz
    for i, x in enumerate(log_x):
        x[0:3] = pivot + Rz @ (x[0:3] - pivot)
        x[3:6] = Rz @ x[3:6]
        x[6:10] = quat_normalize(quat_multiply(q_z, x[6:10]))
        if log_P9 is None or log_std is None:
            continue
        a = np.concatenate([np.cross(up, x[0:3] - pivot), np.cross(up, x[3:6]),
                            quat_to_rotmat(x[6:10]).T @ up])  # fmt: skip
        P = J @ log_P9[i] @ J.T + error.std_rad**2 * np.outer(a, a)
        log_P9[i][:] = 0.5 * (P + P.T)
        log_std[i][0:9] = np.sqrt(np.maximum(np.diag(log_P9[i]), 0.0))


def forward_in_old_frames(x_fwd: F64, t_ns: F64, turns: list[FrameTurn]) -> F64:
    """The forward means ``x_fwd`` (N, nx) with those logged before each frame turn taken
    back into the frame they were made in (a copy): a smoother's corrections of them are that
    frame's (``turn_smoothed`` turns the corrected ones on)."""
    out = np.array(x_fwd, dtype=float, copy=True)
    for turn in reversed(turns):
        rows = np.flatnonzero(np.asarray(t_ns) < turn.t_ns)
        back = HeadingError(-turn.angle_rad, 0.0, 0)
        turn_logged([out[i] for i in rows], None, None, back, turn.up_W, turn.pivot_W)
    return out


def turn_smoothed(x: F64, std: F64, P9: F64, t_ns: F64, turns: list[FrameTurn]) -> None:
    """Turn the smoothed estimates (in place: ``x`` (N, nx), ``std`` (N, ndx), ``P9``
    (N, 9, 9)) made before each frame turn into the frame after it, with its uncertainty."""
    for turn in turns:
        rows = np.flatnonzero(np.asarray(t_ns) < turn.t_ns)
        error = HeadingError(turn.angle_rad, turn.std_rad, 0)
        turn_logged([x[i] for i in rows], [std[i] for i in rows], [P9[i] for i in rows], error,
                    turn.up_W, turn.pivot_W)  # fmt: skip
