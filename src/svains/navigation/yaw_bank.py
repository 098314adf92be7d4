"""A bank of heading hypotheses for an INS started in motion with no heading source.

An ``ins`` started from GPS (``--init gps``) below the course's speed and without a
magnetometer has no heading, and an unaided INS cannot hold the local frame the vision methods
wait in (its horizontal velocity's direction is unknown there, and nothing measures it). A
single UKF started with an arbitrary heading (σ ``init.yaw_std_unknown``, 28.6°) is
collapsed by the first fixes whatever the heading's error, which may be anything up to 180°
(the simulator's 2 m/s village flights started at 15, 30 and 45 s: attitude errors of 43-178°
to the end, NEES 12-70).

:class:`YawBank` is a Gaussian sum over the heading, as PX4's EKF-GSF yaw estimator is for a
drone without a trusted compass: ``n`` copies of the INS filter whose headings split the
circle (the i-th turned by ``2πi/n`` about the start's specific force, which its attitude was
levelled on, through the GPS antenna; yaw σ ``π/n``; every other part of the state and its
covariance the start's) run on the same IMU samples and fuse the same GPS fixes and ranges,
each gated as the filter gates. A fix weighs each copy by how likely its innovation was (at
most one second's worth per second). While the vehicle only cruises every copy explains the
fixes alike; once it accelerates, those pointing wrongly see their velocity run off the
fixes' and lose their weight. When the mixture's heading is known to ``max_std_rad`` (the
spread of the copies' headings about their circular mean, weighted, plus each copy's own
variance), the copies are merged into one Gaussian (moments on the heaviest copy's tangent
space) which replaces the navigator's filter.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.errors import FilterError
from svains.filter.ukf import UKF, UpdateStats
from svains.geometry.rotation import (
    quat_exp,
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    so3_right_jacobian_inv,
)
from svains.models.state import DTH, Q
from svains.models.state import P as POS
from svains.navigation.base import MeasurementBlock
from svains.navigation.fault_handling import add_gap_covariance
from svains.navigation.heading_check import horizontal_basis, yaw_std
from svains.navigation.ins import InsFilter

F64 = NDArray[np.float64]

# The copies' gate without the filter's (``filter.gate_probability`` None): a copy refuses a fix
# beyond this chi-square quantile, and its NIS counts at most that much.
_FIX_PROBABILITY = 0.9999

# The copies are weighed by at most one GPS fix's likelihood per this many seconds (s)
WEIGH_PERIOD_S = 1.0
# The longest a bank runs (s): a vehicle that only cruises never shows its heading, and the
# bank costs its copies' predictions and updates.
YAW_BANK_MAX_S = 120.0


@dataclass(frozen=True)
class BankResult:
    """The bank's merged estimate: mean ``x`` (nx,), covariance ``P`` (ndx, ndx), its
    heading's standard deviation ``std_rad`` and the GPS fixes that weighed the copies
    ``fixes``."""

    x: F64
    P: F64
    std_rad: float
    fixes: int


class YawBank:
    """``n`` copies of an INS filter over the circle of headings (the module docstring)."""

    def __init__(self, ins: InsFilter, up_W: F64, f_W: F64, p_B_G: F64, n: int,
                 max_std_rad: float) -> None:  # fmt: skip
        """Copies of ``ins`` (at its start: its mean and covariance) turned about the start's
        specific force ``f_W`` (3,) m/s² (the direction its attitude was levelled on, ``R f_B
        = f_W``: turned about the vertical instead, every copy but the first disagreed with
        the accelerating start, and a review's KITTI raw start merged 80° off) through the
        GPS antenna (``p_B_G`` (3,) m in the body frame), whose fixed position the start took;
        ``up_W`` (3,) the vertical the headings are counted about; merged once the heading is
        known to ``max_std_rad``."""
        if n < 2:
            raise ValueError(f"a bank of headings needs at least 2 copies, got {n}")
        up = np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)
        axis = np.asarray(f_W, dtype=float) / np.linalg.norm(f_W)
        self._up = up
        self._max_std = float(max_std_rad)
        x0, P0 = ins.ukf.x, ins.ukf.P
        R0 = quat_to_rotmat(x0[Q])
        p_W_A = x0[POS] + R0 @ np.asarray(p_B_G, float)
        P_k = _heading_spread(P0, R0, up, axis, (math.pi / n) ** 2)
        self._axis = level_axis(x0, up)
        self.members: list[InsFilter] = []
        for i in range(n):
            q_z = quat_exp((2.0 * math.pi * i / n) * axis)
            x = x0.copy()
            x[Q] = quat_normalize(quat_multiply(q_z, x0[Q]))
            x[POS] = p_W_A - quat_to_rotmat(x[Q]) @ np.asarray(p_B_G, float)
            member = copy.copy(ins)  # the IMU history and caches shared; its own UKF
            member.ukf = UKF(ins.ukf.manifold, ins.ukf.points, x, P_k)
            self.members.append(member)
        self.log_w = np.full(n, -math.log(n))
        self.fixes = 0
        self._last_weighed_ns: int | None = None

    def propagate(self, t_ns: int, Q9: F64 | None = None) -> None:
        """Every live copy to ``t_ns``, an IMU gap's covariance ``Q9`` (9, 9) added."""
        for i in self._live():
            try:
                self.members[i].propagate_to(t_ns)
            except FilterError:  # (a copy that fails numerically drops out)
                self.log_w[i] = -math.inf
                continue
            if Q9 is not None:
                add_gap_covariance(self.members[i].ukf, Q9)

    def _live(self) -> list[int]:
        return [i for i in range(len(self.members)) if np.isfinite(self.log_w[i])]

    @property
    def alive(self) -> bool:
        """Whether any copy is left."""
        return bool(np.isfinite(self.log_w).any())

    def heaviest(self) -> UKF:
        """The likeliest copy's filter (a live one)."""
        return self.members[int(np.argmax(self.log_w))].ukf

    def update(self, block: MeasurementBlock, gate_probability: float | None,
               t_ns: int | None = None) -> UpdateStats | None:  # fmt: skip
        """Fuse a measurement ``block`` (a GPS fix, a sonar range) taken at ``t_ns`` into every
        live copy that its gate at ``gate_probability`` accepts, and weigh each copy by its
        innovation's likelihood (``N(r; 0, S)``, the NIS capped at the gate: a copy that
        refuses the fix keeps its mean and loses that much; a GPS fix only, tempered to one
        per ``WEIGH_PERIOD_S``). A fix every copy refuses weighs none (a GPS jump
        is no evidence for a heading). A copy whose update fails numerically drops out. The
        update's statistics of the heaviest copy after it (refused by all: the heaviest's
        refusal; None: no live copy)."""
        p = _FIX_PROBABILITY if gate_probability is None else gate_probability
        cap = float(chi2.ppf(p, int(np.size(block.z))))
        stats: dict[int, UpdateStats] = {}
        logdet: dict[int, float] = {}
        for i in self._live():
            ukf = self.members[i].ukf
            try:
                # (``update_blocks`` hands back the innovation covariance it gated on)
                [st] = ukf.update_blocks([(block.h, block.z, block.R, block.residual,
                                           block.name)], p)  # fmt: skip
                assert st.innovation_cov is not None
                L = np.linalg.cholesky(st.innovation_cov)
                logdet[i] = 2.0 * float(np.sum(np.log(np.diag(L))))
                stats[i] = st
            except (FilterError, np.linalg.LinAlgError):
                self.log_w[i] = -math.inf
                stats.pop(i, None)
        if not stats:
            return None
        if not any(st.accepted for st in stats.values()):
            # refused by every copy: no evidence, and recorded as a refusal (a probe found a
            # GPS jump gone from updates.csv)
            return stats[max(stats, key=lambda i: self.log_w[i])]
        # Only GPS fixes weigh the copies (a range does not see the heading), at most one
        # second's worth per second: a 10 Hz receiver's fixes share their errors, and counted
        # as independent they merged a review's flight 39° off, sure to 11°
        if block.name == "gps" and t_ns is not None:
            dt_s = math.inf if self._last_weighed_ns is None else (
                (t_ns - self._last_weighed_ns) * 1e-9)
            power = min(1.0, dt_s / WEIGH_PERIOD_S)
            self._last_weighed_ns = t_ns
            for i, st in stats.items():
                self.log_w[i] += -0.5 * power * (min(st.nis, cap) + logdet[i])
            finite = np.isfinite(self.log_w)
            self.log_w[finite] -= np.logaddexp.reduce(self.log_w[finite])
            self.fixes += 1
        return stats[int(np.argmax(self.log_w))]

    def _yaws(self) -> F64:
        """Each copy's heading (n,) rad (``bank_yaw``)."""
        return np.array([bank_yaw(m.ukf.x, self._up, self._axis) for m in self.members])

    def heading(self) -> tuple[float, float]:
        """The mixture's heading (rad) and its standard deviation (rad): the weighted
        circular mean of the copies' headings, and the weighted mean of each copy's yaw
        variance plus its squared offset from that mean."""
        w = np.exp(self.log_w)
        yaws = self._yaws()
        mean = math.atan2(float(w @ np.sin(yaws)), float(w @ np.cos(yaws)))
        off = np.angle(np.exp(1j * (yaws - mean)))
        var = np.array([yaw_std(m.ukf, self._up) ** 2 for m in self.members])
        return mean, math.sqrt(float(w @ (var + off**2)) / max(float(w.sum()), 1e-300))

    def about_heaviest(self) -> tuple[F64, F64]:
        """The heaviest copy's mean ``x`` (nx,) and the mixture's covariance about it (ndx,
        ndx): each copy's covariance (in the heaviest's tangent) plus its offset's outer
        product, weighted (copies of weight below 1e-6 left out). The estimate while the
        heading is unknown: its yaw variance is the copies' spread, however wide."""
        w, d, P, keep = self._offsets()
        ref = self.heaviest()
        wk = w[keep] / w[keep].sum()
        P_about = sum(wk[n] * (P[n] + np.outer(d[n], d[n])) for n in range(len(keep)))
        return ref.x.copy(), 0.5 * (P_about + P_about.T)

    def _offsets(self) -> tuple[F64, F64, list[F64], list[int]]:
        """The weights (n,); for each kept copy (weight above 1e-6; their indices last) its
        offset from the heaviest on the heaviest's tangent space (k, ndx) and its covariance
        taken into that tangent (a body-frame attitude error ``δ`` of copy i is ``J_r⁻¹(d_i) δ``
        there, ``d_i`` its attitude offset; position, velocity and biases as they are)."""
        w = np.exp(self.log_w)
        ref = self.heaviest()
        keep = [i for i in range(len(w)) if w[i] > 1e-6]
        d = np.array([ref.manifold.local(self.members[i].ukf.x[None, :], ref.x)[0]
                      for i in keep])  # fmt: skip
        P = []
        for n, i in enumerate(keep):
            m = self.members[i].ukf
            T = np.eye(m.P.shape[0])
            T[DTH, DTH] = so3_right_jacobian_inv(d[n][DTH])
            P.append(T @ m.P @ T.T)
        return w, d, P, keep

    def merged(self) -> BankResult | None:
        """The copies merged into one Gaussian once the heading is known to ``max_std_rad``
        (moments on the tangent space of the heaviest copy, copies of weight below 1e-6 left
        out), else None."""
        if self.fixes == 0 or not np.isfinite(self.log_w).any():
            return None
        _, std = self.heading()
        if std > self._max_std:
            return None
        w, d, P, keep = self._offsets()
        ref = self.heaviest()
        wk = w[keep] / w[keep].sum()
        d_mean = wk @ d
        x = ref.manifold.retract(ref.x[None, :], d_mean[None, :])[0]
        P_m = sum(wk[n] * (P[n] + np.outer(d[n] - d_mean, d[n] - d_mean))
                  for n in range(len(keep)))  # fmt: skip
        return BankResult(x, 0.5 * (P_m + P_m.T), std, self.fixes)


def _heading_spread(P0: F64, R0: F64, up: F64, axis: F64, var: float) -> F64:
    """``P0`` (ndx, ndx) with its heading variance about ``up`` (3,) brought down to its tilt
    variance (the mean of the two horizontal directions'), then ``var`` (rad²) about ``axis``
    (3,) instead: the body-frame attitude errors along ``R0ᵀ up`` and ``R0ᵀ axis``."""
    n = P0.shape[0]

    def along(v_W: F64) -> F64:
        u = np.zeros(n)
        u[DTH] = R0.T @ v_W
        return u

    E = horizontal_basis(up)
    tilt_var = 0.5 * sum(float(along(e) @ P0 @ along(e)) for e in E)
    u_up, u_ax = along(up), along(axis)
    P = P0 + (tilt_var - float(u_up @ P0 @ u_up)) * np.outer(u_up, u_up)
    return P + (var - float(u_ax @ P @ u_ax)) * np.outer(u_ax, u_ax)


def level_axis(x: F64, up_W: F64) -> int:
    """The body axis (0: x, 1: y) of the state ``x`` (nx,) most nearly horizontal: the one
    whose heading ``bank_yaw`` takes."""
    R = quat_to_rotmat(x[Q])
    return int(np.argmin(np.abs(np.asarray(up_W, float) @ R[:, :2])))


def bank_yaw(x: F64, up_W: F64, axis: int) -> float:
    """The heading (rad) of the state ``x`` (nx,): the angle of its body ``axis`` (0: x, 1: y)
    in the world's horizontal basis (``heading_check.horizontal_basis`` of the unit vertical
    ``up_W`` (3,)), counted about the vertical."""
    h = horizontal_basis(np.asarray(up_W, float)) @ quat_to_rotmat(x[Q])[:, axis]
    return math.atan2(float(h[1]), float(h[0]))
