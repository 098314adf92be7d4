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
circle (the i-th turned by ``2πi/n`` about the vertical, yaw σ ``π/n``, every other part of
the state and its covariance the start's) run on the same IMU samples and fuse the same GPS
fixes, each weighted by how likely its innovations were. While the vehicle only cruises
every copy explains the fixes alike; once it accelerates, those pointing wrongly see their
velocity run off the fixes' and lose their weight. When the mixture's heading is known to
``max_std_rad`` (the spread of the copies' headings about their circular mean, weighted,
plus each copy's own variance), the copies are merged into one Gaussian (moments about the
heaviest copy, on its tangent space) which replaces the navigator's filter.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.errors import FilterError
from svains.filter.ukf import UKF, UpdateStats
from svains.geometry.rotation import quat_exp, quat_multiply, quat_normalize, quat_to_rotmat
from svains.models.state import DTH, Q
from svains.models.state import P as POS
from svains.navigation.base import MeasurementBlock
from svains.navigation.fault_handling import add_gap_covariance
from svains.navigation.heading_check import horizontal_basis, yaw_std
from svains.navigation.ins import InsFilter

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

# A fix every copy finds beyond this chi-square quantile weighs none of them (a GPS jump is no
# evidence for one heading), and one copy's NIS counts at most that much (one outlier fix
# cannot outweigh the fixes before it).
_FIX_PROBABILITY = 0.9999

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

    def __init__(self, ins: InsFilter, up_W: F64, p_B_G: F64, n: int,
                 max_std_rad: float) -> None:  # fmt: skip
        """Copies of ``ins`` (at its start: its mean and covariance) turned about the unit
        vertical ``up_W`` (3,) through the GPS antenna (``p_B_G`` (3,) m in the body frame),
        whose fixed position the start took; merged once the heading is known to
        ``max_std_rad``."""
        if n < 2:
            raise ValueError(f"a bank of headings needs at least 2 copies, got {n}")
        up = np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)
        self._up = up
        self._max_std = float(max_std_rad)
        x0, P0 = ins.ukf.x, ins.ukf.P
        R0 = quat_to_rotmat(x0[Q])
        p_W_A = x0[POS] + R0 @ np.asarray(p_B_G, float)
        # yaw in the body tangent: δθ_B along R^T up (a world turn leaves it as it was)
        u = np.zeros(P0.shape[0])
        u[DTH] = R0.T @ up
        var_yaw = (math.pi / n) ** 2
        P_k = P0 + (var_yaw - float(u @ P0 @ u)) * np.outer(u, u)
        self._axis = level_axis(x0, up)
        self.members: list[InsFilter] = []
        for i in range(n):
            q_z = quat_exp((2.0 * math.pi * i / n) * up)
            x = x0.copy()
            x[Q] = quat_normalize(quat_multiply(q_z, x0[Q]))
            x[POS] = p_W_A - quat_to_rotmat(x[Q]) @ np.asarray(p_B_G, float)
            member = copy.copy(ins)  # the IMU history and caches shared; its own UKF
            member.ukf = UKF(ins.ukf.manifold, ins.ukf.points, x, P_k)
            self.members.append(member)
        self.log_w = np.full(n, -math.log(n))
        self.fixes = 0

    def propagate(self, t_ns: int, Q9: F64 | None = None) -> None:
        """Every live copy to ``t_ns``, an IMU gap's covariance ``Q9`` (9, 9) added."""
        for i in self._live():
            self.members[i].propagate_to(t_ns)
            if Q9 is not None:
                add_gap_covariance(self.members[i].ukf, Q9)

    def _live(self) -> list[int]:
        return [i for i in range(len(self.members)) if np.isfinite(self.log_w[i])]

    def update(self, block: MeasurementBlock) -> UpdateStats | None:
        """Fuse a measurement ``block`` (a GPS fix, a sonar range) into every live copy and
        weigh each by its innovation's likelihood (``N(r; 0, S)``, the NIS capped at
        ``_FIX_PROBABILITY``'s quantile); a fix every copy finds beyond that quantile is fused
        by none. A copy whose update fails numerically drops out. The update's statistics of
        the heaviest copy after it (None: fused by none)."""
        live = self._live()
        dof = int(np.size(block.z))
        cap = float(chi2.ppf(_FIX_PROBABILITY, dof))
        looks: dict[int, tuple[float, float]] = {}  # NIS and log det(S) before the update
        for i in live:
            ukf = self.members[i].ukf
            try:
                X, _ = ukf.sigma_points()
                S, r = _innovation(ukf, X, block)
                L = np.linalg.cholesky(S)
            except (FilterError, np.linalg.LinAlgError):
                self.log_w[i] = -math.inf
                continue
            w = np.linalg.solve(L, r)
            looks[i] = (float(w @ w), 2.0 * float(np.sum(np.log(np.diag(L)))))
        if not looks or min(nis for nis, _ in looks.values()) > cap:
            return None
        stats: dict[int, UpdateStats] = {}
        for i, (nis, logdet) in looks.items():
            ukf = self.members[i].ukf
            try:
                stats[i] = ukf.update(block.h, block.z, block.R, None, block.residual,
                                      block.name)  # fmt: skip
            except FilterError:
                self.log_w[i] = -math.inf
                continue
            self.log_w[i] += -0.5 * (min(nis, cap) + logdet)
        finite = np.isfinite(self.log_w)
        if not finite.any():
            return None
        self.log_w[finite] -= np.logaddexp.reduce(self.log_w[finite])
        self.fixes += block.name == "gps"
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
        ndx): each copy's covariance plus its offset's outer product, weighted (copies of
        weight below 1e-6 left out). The estimate while the heading is unknown: its yaw
        variance is the copies' spread, however wide."""
        w, d, keep = self._offsets()
        ref = self.members[int(np.argmax(w))].ukf
        P = sum(w[i] * (self.members[i].ukf.P + np.outer(d[n], d[n]))
                for n, i in enumerate(keep))  # fmt: skip
        return ref.x.copy(), 0.5 * (P + P.T) / float(w[keep].sum())

    def _offsets(self) -> tuple[F64, F64, list[int]]:
        """The weights (n,), each kept copy's offset from the heaviest on its tangent space
        (k, ndx) and the kept copies' indices (weight above 1e-6)."""
        w = np.exp(self.log_w)
        ref = self.members[int(np.argmax(w))].ukf
        keep = [i for i in range(len(w)) if w[i] > 1e-6]
        d = np.array([ref.manifold.local(self.members[i].ukf.x[None, :], ref.x)[0]
                      for i in keep])  # fmt: skip
        return w, d, keep

    def merged(self) -> BankResult | None:
        """The copies merged into one Gaussian once the heading is known to ``max_std_rad``
        (moments on the tangent space of the heaviest copy, copies of weight below 1e-6 left
        out), else None."""
        if self.fixes == 0 or not np.isfinite(self.log_w).any():
            return None
        _, std = self.heading()
        if std > self._max_std:
            return None
        w, d, keep = self._offsets()
        ref = self.members[int(np.argmax(w))].ukf
        wk = w[keep] / w[keep].sum()
        d_mean = wk @ d
        x = ref.manifold.retract(ref.x[None, :], d_mean[None, :])[0]
        P = sum(wk[n] * (self.members[i].ukf.P + np.outer(d[n] - d_mean, d[n] - d_mean))
                for n, i in enumerate(keep))  # fmt: skip
        return BankResult(x, 0.5 * (P + P.T), std, self.fixes)


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


def _innovation(ukf: UKF, X: F64, block: MeasurementBlock) -> tuple[F64, F64]:
    """The innovation's covariance ``S`` (nz, nz) and the innovation ``r`` (nz,) of ``block``
    over the sigma points ``X``."""
    Wm, Wc = ukf.points.Wm, ukf.points.Wc
    z = np.ravel(block.z)
    Y = np.reshape(block.h(X), (X.shape[0], z.size))
    y = Wm @ Y
    dY = Y - y if block.residual is None else block.residual(Y, y)
    r = z - y if block.residual is None else block.residual(z, y)
    R = np.asarray(block.R, dtype=float)
    S = dY.T @ (Wc[:, None] * dY) + (np.diag(R) if R.ndim == 1 else R)
    return 0.5 * (S + S.T), r
