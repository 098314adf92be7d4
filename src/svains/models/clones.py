"""Stochastic cloning: the navigation state augmented with copies of past body poses.

State ``x`` = navigation block (nx numbers, ``models.state``), then ``n_calib`` calibration
numbers (optional; Euclidean, equal in ``x`` and the tangent: e.g. the camera-IMU rotation
correction ``δφ_C`` (3, rad) of ``navigation.vision_clones``), then ``n_aux`` auxiliary numbers
(optional, Euclidean: e.g. the step a bias alarm injected, ``navigation.bias_recall``), then K
clones, each ``(p_W_B (3, m), q_W_B_wxyz (4))`` at a past frame time: nx + n_calib + n_aux + 7K
numbers. Tangent ``dx`` = navigation tangent (ndx), the calibration and auxiliary numbers, then
each clone's ``(δp (3, m), δθ_B (3, rad))``, the attitude error on the right as everywhere else
(``q = q̂ ⊗ Exp(δθ_B)``): ndx + n_calib + n_aux + 6K numbers. The process model leaves the
calibration and auxiliary numbers constant, like the clones. The first ``n_consider``
calibration numbers may be *consider* parameters (``consider``): carried with their covariance
and never updated (``filter.manifold``; the camera rotation's error as the run measures it,
``navigation.vision_clones``).

A clone is an exact copy of the current pose, so its tangent error equals the navigation
block's ``(δp, δθ_B)``: augmenting is ``x' = (x, p, q)`` and ``P' = J P J^T`` with the
selection ``J = [I; S]`` (cross-covariances included). Marginalising a clone deletes its rows
and columns. The process model never touches the clones (the IMU propagators copy every column
beyond the navigation block; ``UKF.predict`` adds ``Q`` to the navigation block only), so a
clone keeps its value and its correlation with the propagated state evolves through the sigma
points: the relative motion between the clone time and now is then a function of the state.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError
from svains.geometry.rotation import quat_to_rotmat, so3_log
from svains.models._quat import qexp, qlog, qmul
from svains.models.manifold import NavManifold, quat_mean
from svains.models.state import DP, DTH
from svains.models.state import P as P_SLICE
from svains.models.state import Q as Q_SLICE
from svains.models.time_offset import (
    ShiftIncrement,
    ShiftTable,
    shifted_pose,
    shifted_pose_jacobian,
)

F64 = NDArray[np.float64]

CLONE_NX = 7  # p_W_B (3), q_W_B_wxyz (4)
CLONE_NDX = 6  # δp (3), δθ_B (3)


@dataclass(frozen=True)
class CloneManifold:
    """Box-plus/minus and mean of the navigation block plus ``n_clones`` pose clones."""

    nav: NavManifold
    n_clones: int = 0
    n_calib: int = 0
    n_aux: int = 0
    n_consider: int = 0

    @cached_property
    def n_euclid(self) -> int:
        """Euclidean numbers between the navigation block and the clones: calibration, aux."""
        return self.n_calib + self.n_aux

    # Cached (the dataclass is frozen): read several times per sigma-point operation.
    @cached_property
    def nx(self) -> int:
        return self.nav.nx + self.n_euclid + CLONE_NX * self.n_clones

    @cached_property
    def ndx(self) -> int:
        return self.nav.ndx + self.n_euclid + CLONE_NDX * self.n_clones

    @property
    def calib(self) -> tuple[slice, slice] | None:
        """Columns of the calibration block in ``x`` and in the tangent (None: no block)."""
        if self.n_calib == 0:
            return None
        return (slice(self.nav.nx, self.nav.nx + self.n_calib),
                slice(self.nav.ndx, self.nav.ndx + self.n_calib))

    @property
    def consider(self) -> tuple[slice, slice] | None:
        """Columns of the consider parameters (the calibration block's first ``n_consider``)
        in ``x`` and in the tangent (None: none); the UKF never updates them."""
        if self.n_consider == 0:
            return None
        return (slice(self.nav.nx, self.nav.nx + self.n_consider),
                slice(self.nav.ndx, self.nav.ndx + self.n_consider))

    @staticmethod
    def clone_jitter(variances: F64) -> F64:
        """Variance to add (k,) to the diagonal entries ``variances`` (k,) of a clone that
        copies them: ``max(CLONE_JITTER, CLONE_JITTER_REL·variance)`` (see ``CLONE_JITTER``)."""
        return np.maximum(CLONE_JITTER, CLONE_JITTER_REL * np.asarray(variances, dtype=float))

    @property
    def aux(self) -> tuple[slice, slice] | None:
        """Columns of the auxiliary block in ``x`` and in the tangent (None: no block)."""
        if self.n_aux == 0:
            return None
        a, b = self.nav.nx + self.n_calib, self.nav.ndx + self.n_calib
        return slice(a, a + self.n_aux), slice(b, b + self.n_aux)

    def with_clones(self, n_clones: int) -> CloneManifold:
        """The same layout with ``n_clones`` clones."""
        return CloneManifold(self.nav, n_clones, self.n_calib, self.n_aux, self.n_consider)

    def with_aux(self, n_aux: int) -> CloneManifold:
        """The same layout with an auxiliary block of ``n_aux`` numbers."""
        return CloneManifold(self.nav, self.n_clones, self.n_calib, n_aux, self.n_consider)

    def columns(self, i: int) -> tuple[slice, slice]:
        """Columns of clone ``i`` in ``x``: ``(p_W_B, q_W_B_wxyz)`` slices."""
        if not 0 <= i < self.n_clones:
            raise ConfigError(f"clone index {i} out of range (the state has {self.n_clones})")
        a = self.nav.nx + self.n_euclid + CLONE_NX * i
        return slice(a, a + 3), slice(a + 3, a + 7)

    def tangent(self, i: int) -> slice:
        """Columns of clone ``i``'s ``(δp, δθ_B)`` in the tangent vector."""
        if not 0 <= i < self.n_clones:
            raise ConfigError(f"clone index {i} out of range (the state has {self.n_clones})")
        a = self.nav.ndx + self.n_euclid + CLONE_NDX * i
        return slice(a, a + CLONE_NDX)

    def _split(self, X: F64) -> tuple[F64, F64]:
        """Clone positions (S, K, 3) and quaternions as (4, S, K) from (S, nx)."""
        C = X[:, self.nav.nx + self.n_euclid :].reshape(X.shape[0], self.n_clones, CLONE_NX)
        # ``transpose`` is the view ``np.moveaxis`` returns, without its argument checks
        # (measurable at 4 calls per frame).
        return C[..., :3], C[..., 3:].transpose(2, 0, 1)

    def retract(self, X: F64, dX: F64) -> F64:
        """``X ⊞ dX``: (S, nx), (S, ndx) -> (S, nx)."""
        nav = self.nav
        out = np.empty((X.shape[0], self.nx))
        out[:, : nav.nx] = nav.retract(X[:, : nav.nx], dX[:, : nav.ndx])
        nc = self.n_euclid
        if nc:
            cx, cdx = slice(nav.nx, nav.nx + nc), slice(nav.ndx, nav.ndx + nc)
            out[:, cx] = X[:, cx] + dX[:, cdx]
        if self.n_clones == 0:
            return out
        p, q = self._split(X)
        d = dX[:, nav.ndx + nc :].reshape(X.shape[0], self.n_clones, CLONE_NDX)
        qn = qmul(q, qexp(d[..., 3:].transpose(2, 0, 1)))
        qn /= np.sqrt((qn * qn).sum(axis=0))
        C = out[:, nav.nx + nc :].reshape(X.shape[0], self.n_clones, CLONE_NX)
        C[..., :3] = p + d[..., :3]
        C[..., 3:] = qn.transpose(1, 2, 0)
        return out

    def local(self, X: F64, x_ref: F64) -> F64:
        """``X ⊟ x_ref``: (S, nx), (nx,) -> (S, ndx)."""
        nav = self.nav
        out = np.empty((X.shape[0], self.ndx))
        out[:, : nav.ndx] = nav.local(X[:, : nav.nx], x_ref[: nav.nx])
        nc = self.n_euclid
        if nc:
            cx, cdx = slice(nav.nx, nav.nx + nc), slice(nav.ndx, nav.ndx + nc)
            out[:, cdx] = X[:, cx] - x_ref[cx]
        if self.n_clones == 0:
            return out
        p, q = self._split(X)
        p0, q0 = self._split(x_ref[None, :])
        conj = q0 * np.array([1.0, -1.0, -1.0, -1.0])[:, None, None]
        d = out[:, nav.ndx + nc :].reshape(X.shape[0], self.n_clones, CLONE_NDX)
        d[..., :3] = p - p0
        d[..., 3:] = qlog(qmul(conj, q)).transpose(1, 2, 0)
        return out

    def mean(self, X: F64, w: F64) -> F64:
        """Weighted mean: the navigation block's, calibration, auxiliary numbers and clone
        positions summed, clone attitudes by the same intrinsic quaternion mean as the navigation
        attitude."""
        nav = self.nav
        out = np.empty(self.nx)
        out[: nav.nx] = nav.mean(X[:, : nav.nx], w)
        out[nav.nx : nav.nx + self.n_euclid] = w @ X[:, nav.nx : nav.nx + self.n_euclid]
        for i in range(self.n_clones):
            cp, cq = self.columns(i)
            out[cp] = w @ X[:, cp]
            out[cq] = quat_mean(X[:, cq], w)
        return out


# Variance added to each diagonal entry of a new clone's own block: ``CLONE_JITTER_REL`` times
# that entry (the pose variance it copies), never less than ``CLONE_JITTER`` (m², rad²). An
# exact copy makes P singular, and the sigma points need its Cholesky factor, whose rounding
# error is relative to each entry's scale: about n·eps (1e-14) of it, so an absolute 1e-12 is
# lost under a position variance of 1e4 m². 1e-9 of the entry stays 1e4 above that rounding
# and costs nothing measurable (the clone-pose difference gets 3e-5 of the pose's deviation);
# the floor (1 µm, 1 µrad) covers tiny variances.
CLONE_JITTER = 1e-12
CLONE_JITTER_REL = 1e-9


def _checked(x: F64, P: F64, manifold: CloneManifold) -> tuple[F64, F64]:
    """``x`` (nx,), ``P`` (ndx, ndx) as float arrays, refused when they do not fit ``manifold``."""
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    if x.shape != (manifold.nx,) or P.shape != (manifold.ndx, manifold.ndx):
        raise ConfigError(
            f"x {x.shape} / P {P.shape} do not match nx={manifold.nx}, ndx={manifold.ndx}"
        )
    return x, P


def _appended(
    x: F64, P_new: F64, manifold: CloneManifold, p_W_B: F64, q_W_B_wxyz: F64,
    jitter: float | None,
) -> tuple[F64, F64, CloneManifold]:
    """The state with the clone ``(p_W_B, q_W_B_wxyz)`` appended, given its covariance
    ``P_new`` (ndx + 6, ndx + 6) before the jitter (see ``augment_clone``)."""
    n = manifold.ndx
    c = np.arange(n, n + CLONE_NDX)
    P_new[c, c] += CloneManifold.clone_jitter(P_new[c, c]) if jitter is None else jitter
    x_new = np.concatenate([x, p_W_B, q_W_B_wxyz])
    return x_new, 0.5 * (P_new + P_new.T), manifold.with_clones(manifold.n_clones + 1)


def augment_clone(
    x: F64, P: F64, manifold: CloneManifold, jitter: float | None = None
) -> tuple[F64, F64, CloneManifold]:
    """Append a clone of the current body pose: ``x'`` (nx + 7,), ``P'`` (ndx + 6, ndx + 6).

    Exact: the clone's error is the navigation block's ``(δp, δθ_B)``, so ``P' = J P J^T`` with
    ``J`` the identity stacked on that selection (the new clone is fully correlated with now),
    plus a jitter on the clone's own diagonal that keeps P positive definite: by default
    ``CloneManifold.clone_jitter`` of each pose variance (``max(CLONE_JITTER,
    CLONE_JITTER_REL·P_ii)``, scale-relative), or the absolute ``jitter`` given (0: exact copy).
    """
    x, P = _checked(x, P, manifold)
    # ``J P J^T`` with J the identity stacked on the pose's rows of the tangent: J only
    # selects rows, so indexing gives the same numbers without the two products.
    rows = np.arange(manifold.ndx)
    J_rows = np.concatenate([rows, rows[DP], rows[DTH]])
    return _appended(x, P[np.ix_(J_rows, J_rows)], manifold, x[P_SLICE], x[Q_SLICE], jitter)


def augment_independent_clone(
    x: F64, P: F64, manifold: CloneManifold, p_W_B: F64, q_W_B_wxyz: F64, P_pose: F64
) -> tuple[F64, F64, CloneManifold]:
    """Append a pose ``(p_W_B (3,) m, q_W_B_wxyz (4,))`` with its own covariance ``P_pose``
    (6, 6; tangent ``(δp, δθ_B)``) and no correlation with the state: ``x'`` (nx + 7,),
    ``P'`` (ndx + 6, ndx + 6). For a pose estimated long ago and stored apart from the
    filter (a keyframe, ``navigation.relocalise``), whose correlation with the state the
    filter no longer holds."""
    x, P = _checked(x, P, manifold)
    P_pose = np.asarray(P_pose, dtype=float)
    if P_pose.shape != (CLONE_NDX, CLONE_NDX):
        raise ConfigError(f"a pose covariance is ({CLONE_NDX}, {CLONE_NDX}), got {P_pose.shape}")
    n = manifold.ndx
    P_new = np.zeros((n + CLONE_NDX, n + CLONE_NDX))
    P_new[:n, :n] = P
    P_new[n:, n:] = P_pose
    q = np.asarray(q_W_B_wxyz, dtype=float)
    return _appended(x, P_new, manifold, np.asarray(p_W_B, dtype=float), q / np.linalg.norm(q),
                     None)  # fmt: skip


def shifted_clone(
    x: F64, manifold: CloneManifold, td: int, inc: ShiftIncrement | ShiftTable
) -> tuple[F64, F64, F64]:
    """The body pose at the image's IMU time ``t + t_d`` (``t_d = x[td]``, s, in the state's
    calibration block, equal to ``inc.tau_s``; ``models.time_offset``): ``p_W_B`` (3,),
    ``q_W_B_wxyz`` (4,) and its Jacobian ``S`` (6, ndx) over the state's tangent
    (``shifted_pose_jacobian``)."""
    calib = manifold.calib
    if calib is None or not calib[0].start <= td < calib[0].stop:
        raise ConfigError(f"column {td} is not in the state's calibration block")
    td_tangent = td - calib[0].start + calib[1].start
    return shifted_pose_jacobian(np.asarray(x, dtype=float), manifold.ndx, td, td_tangent, inc)


def augment_shifted_clone(
    x: F64, P: F64, manifold: CloneManifold, td: int, inc: ShiftIncrement | ShiftTable,
    jitter: float | None = None,
) -> tuple[F64, F64, CloneManifold]:
    """Append a clone of the body pose at the image's IMU time ``t + t_d`` (``shifted_clone``),
    first order in ``t_d`` (the filter uses ``augment_shifted_clone_sigma``, which reduces to
    this for a narrow offset): ``x'`` (nx + 7,), ``P'`` (ndx + 6, ndx + 6).
    ``P' = J P J^T`` with ``J = [I; S]``: the clone is correlated with the offset, so the
    relative motion to a later shifted pose depends on ``t_d`` at both ends. Jitter as in
    ``augment_clone``."""
    x, P = _checked(x, P, manifold)
    p_c, q_c, S = shifted_clone(x, manifold, td, inc)
    J = np.vstack([np.eye(manifold.ndx), S])
    return _appended(x, J @ P @ J.T, manifold, p_c, q_c, jitter)


# Gauss-Hermite nodes (in σ) and weights over the offset for ``augment_shifted_clone_sigma``:
# five nodes are exact for polynomials to degree 9, so a quadratic motion's mean and variance are.
_GH_NODES, _GH_WEIGHTS = np.polynomial.hermite_e.hermegauss(5)
_GH_WEIGHTS = _GH_WEIGHTS / _GH_WEIGHTS.sum()
SHIFT_REACH_SIGMA = float(_GH_NODES.max())  # 2.86: the farthest node, in offset σ


def augment_shifted_clone_sigma(
    x: F64, P: F64, manifold: CloneManifold, td: int, table: ShiftIncrement | ShiftTable,
    jitter: float | None = None,
) -> tuple[F64, F64, CloneManifold, F64]:
    """``augment_shifted_clone`` with the offset's spread taken through quadrature: ``x'``
    (nx + 7,), ``P'`` (ndx + 6, ndx + 6), the manifold and the clone's linear map ``S`` (6, ndx)
    over the state's tangent (``shifted_pose_jacobian``; a smoother's transform).

    The pose at ``t + t_d`` is linear in the pose, velocity and attitude errors, not in ``t_d``:
    the IMU's motion over tens of ms curves. While the offset is uncertain by that much the
    first-order clone misses the curvature (about a pixel at the start of a run with a 50 ms
    offset and a 20 ms prior) and keeps that error until it is replaced. Here the pose is also
    evaluated at five Gauss-Hermite offsets ``τ + n_i σ`` through ``table`` (a ``ShiftTable``
    reaching ``SHIFT_REACH_SIGMA σ``; a ``ShiftIncrement``: first order from one increment), as
    the vision models move the current pose: the clone's mean is their weighted mean, and what
    the first-order slope ``(v_τ, ω_τ)`` leaves unexplained over the spread is added to the
    clone's own variance. The slope stays the IMU's at the estimate: on a vibrating platform the
    regression slope over ±57 ms is a different draw of the vibration, and with it EuRoC's static
    start drifted 32 mm in 4.6 s instead of 3 (``docs/results/time-offset.md``)."""
    x, P = _checked(x, P, manifold)
    center = table.center if isinstance(table, ShiftTable) else table
    p_0, q_0, S = shifted_clone(x, manifold, td, center)  # checks ``td``
    assert manifold.calib is not None
    k = td - manifold.calib[0].start + manifold.calib[1].start  # the offset's tangent column
    sd = float(np.sqrt(max(P[k, k], 0.0)))
    u = _GH_NODES * sd  # (5,) s from the estimate
    X = np.repeat(x[None, :], u.size, axis=0)
    X[:, td] += u
    R, p = shifted_pose(X, td, table)
    R_0 = quat_to_rotmat(q_0)
    g = np.concatenate([p - p_0, so3_log(R_0.T @ R)], axis=1)  # (5, 6)
    w = _GH_WEIGHTS
    g_mean = w @ g
    dg = g - g_mean
    rest = dg - np.outer(u, S[:, k])
    J = np.vstack([np.eye(manifold.ndx), S])
    P_new = J @ P @ J.T
    P_new[-CLONE_NDX:, -CLONE_NDX:] += (rest * w[:, None]).T @ rest
    q_mean = qmul(q_0, qexp(g_mean[3:]))
    q_mean /= np.linalg.norm(q_mean)
    x_new, P_new, m = _appended(x, P_new, manifold, p_0 + g_mean[:3], q_mean, jitter)
    return x_new, P_new, m, S


def marginalize_clone(
    x: F64, P: F64, manifold: CloneManifold, i: int
) -> tuple[F64, F64, CloneManifold]:
    """Drop clone ``i``: its 7 numbers from ``x`` and its 6 rows/columns from ``P``."""
    cp, cq = manifold.columns(i)
    dt = manifold.tangent(i)
    keep_x = np.r_[0 : cp.start, cq.stop : manifold.nx]
    keep_dx = np.r_[0 : dt.start, dt.stop : manifold.ndx]
    P = np.asarray(P, dtype=float)
    return (
        np.asarray(x, dtype=float)[keep_x],
        P[np.ix_(keep_dx, keep_dx)],
        manifold.with_clones(manifold.n_clones - 1),
    )


def as_clone_manifold(manifold: object) -> CloneManifold:
    """``manifold`` as a ``CloneManifold`` (a bare ``NavManifold`` wrapped with no clones)."""
    if isinstance(manifold, CloneManifold):
        return manifold
    if not isinstance(manifold, NavManifold):
        raise ConfigError(f"expected the navigation manifold, got {type(manifold).__name__}")
    return CloneManifold(manifold, 0)


def _insert_block(x: F64, P: F64, manifold: CloneManifold, offset: int, value: F64,
                  cov: F64) -> tuple[F64, F64]:  # fmt: skip
    """``x``, ``P`` with a Euclidean block (``value`` (n,), covariance ``cov`` (n, n),
    uncorrelated with the rest) inserted ``offset`` numbers after the navigation block."""
    n = value.size
    a, b = manifold.nav.nx + offset, manifold.nav.ndx + offset
    x_new = np.concatenate([x[:a], value, x[a:]])
    P_new = np.zeros((manifold.ndx + n, manifold.ndx + n))
    keep = np.r_[0:b, b + n : manifold.ndx + n]
    P_new[np.ix_(keep, keep)] = P
    P_new[b : b + n, b : b + n] = cov
    return x_new, P_new


def augment_calibration(
    x: F64, P: F64, manifold: CloneManifold, value: F64, cov: F64
) -> tuple[F64, F64, CloneManifold]:
    """Insert a calibration block (``value`` (n,), covariance ``cov`` (n, n), uncorrelated with
    the rest) after the navigation block of a state that has none: ``x'``, ``P'``, manifold."""
    if manifold.n_calib:
        raise ConfigError(f"the state already has a calibration block of {manifold.n_calib}")
    value = np.asarray(value, dtype=float)
    x_new, P_new = _insert_block(x, P, manifold, 0, value, cov)
    return x_new, P_new, CloneManifold(manifold.nav, manifold.n_clones, value.size,
                                       manifold.n_aux)  # fmt: skip


def augment_consider(
    x: F64, P: F64, manifold: CloneManifold, cov: F64
) -> tuple[F64, F64, CloneManifold]:
    """Insert consider parameters (zero mean, covariance ``cov`` (n, n), uncorrelated with the
    rest) at the front of the calibration block of a state that has none (any estimated
    calibration numbers follow them): ``x'``, ``P'``, manifold."""
    if manifold.n_consider:
        raise ConfigError(f"the state already has {manifold.n_consider} consider parameters")
    cov = np.asarray(cov, dtype=float)
    n = cov.shape[0]
    x_new, P_new = _insert_block(x, P, manifold, 0, np.zeros(n), cov)
    return x_new, P_new, CloneManifold(manifold.nav, manifold.n_clones, manifold.n_calib + n,
                                       manifold.n_aux, n)  # fmt: skip


def augment_aux(x: F64, P: F64, manifold: CloneManifold, n: int) -> tuple[F64, F64, CloneManifold]:
    """Insert an auxiliary block of ``n`` zeros with zero covariance after the calibration block
    of a state that has none (the caller gives it its covariance): ``x'``, ``P'``, manifold."""
    if manifold.n_aux:
        raise ConfigError(f"the state already has an auxiliary block of {manifold.n_aux}")
    x_new, P_new = _insert_block(x, P, manifold, manifold.n_calib, np.zeros(n), np.zeros((n, n)))
    return x_new, P_new, manifold.with_aux(n)


def marginalize_aux(x: F64, P: F64, manifold: CloneManifold) -> tuple[F64, F64, CloneManifold]:
    """Drop the auxiliary block: its numbers from ``x`` and its rows/columns from ``P``."""
    if manifold.aux is None:
        return x, P, manifold
    ax, adx = manifold.aux
    keep_x = np.r_[0 : ax.start, ax.stop : manifold.nx]
    keep_dx = np.r_[0 : adx.start, adx.stop : manifold.ndx]
    return x[keep_x], P[np.ix_(keep_dx, keep_dx)], manifold.with_aux(0)
