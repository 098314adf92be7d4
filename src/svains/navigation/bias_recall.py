"""Confirming a bias alarm: the step it injected kept as states, undone exactly on a false alarm.

A bias alarm (``ConsistencyMonitor.biased``) widens the IMU biases so that the next fixes can
move them. On a false alarm (1 % of windows at the 0.99 quantile on white innovations) what the
filter knew of them was right, and without it a GPS outage soon after is crossed on biases
learnt from two or three fixes (a simulated ``ins`` outage: 2.36 m → 22.5 m).

So the widening is a step ``n`` (12,) ~ N(0, diag(q)) added to the gyro and accelerometer
biases, the attitude and the velocity (:func:`inject_step`), and ``n`` itself stays in the
state as auxiliary numbers (``CloneManifold.aux``, constant in the process model, like a
clone): every later update learns the step and keeps its correlation with the rest of the state.
The alarm also keeps the biases' mean ``b₀`` (6,) and covariance ``P₀`` (6, 6) from just before
it (:class:`BiasAlarm`) and tests, after every group of updates, whether the biases learnt since
have left them: ``r = b − b₀`` against ``S = P_b + P₀ + Q_rw τ`` (the random walk over the τ
since the alarm), :func:`bias_change_nis`.

- Beyond the ``probability`` quantile (6 dof): the step is confirmed; ``n`` is marginalised
  (:func:`drop_step`) and the widened filter goes on.
- Still inside it when the GPS falls silent (an outage, where nothing can confirm a step) or
  ``confirm_s`` after the alarm: no step happened. The filter is conditioned on ``n = 0``
  (:func:`undo_step`): for a linear-Gaussian model that is exactly the filter that was never
  widened, since the step enters additively and everything fused since is kept; nothing is
  counted twice. (Before, ``b₀`` was fused as an independent measurement of the biases, which
  counted the data before the alarm a second time.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError
from svains.filter.ukf import UKF, UpdateStats
from svains.models.clones import CloneManifold, as_clone_manifold, augment_aux, marginalize_aux
from svains.models.state import BA, BG, DBA, DBG, DTH, DV

F64 = NDArray[np.float64]
_X_BIAS = np.r_[np.arange(BG.start, BG.stop), np.arange(BA.start, BA.stop)]  # x columns
_DX_BIAS = np.r_[np.arange(DBG.start, DBG.stop), np.arange(DBA.start, DBA.stop)]  # tangent rows
# Tangent rows a step moves, in the order of its 12 numbers: gyro bias, accelerometer bias,
# attitude δθ_B, velocity.
STEP_ROWS = np.r_[_DX_BIAS, np.arange(DTH.start, DTH.stop), np.arange(DV.start, DV.stop)]
STEP_SIZE = STEP_ROWS.size
# Floor of each step variance, relative to the variance of the row it moves: a zero entry (a
# bias already at its cap, no elapsed time) would leave an auxiliary number known exactly and P
# singular; 1e-6 of the row's variance is far below anything the filter resolves.
STEP_FLOOR_REL = 1e-6
# Noise of the n = 0 pseudo-measurement relative to the step's own variance: the conditioning
# is exact to this fraction.
UNDO_NOISE_REL = 1e-9


def inject_step(ukf: UKF, var: F64) -> None:
    """Add a step ``n`` ~ N(0, diag(``var``)) (12,: gyro bias (rad/s)², accelerometer bias
    (m/s²)², attitude rad², velocity (m/s)²) to those rows of the state, and keep ``n`` as the
    auxiliary block (appended at zero mean when the state has none; a second step adds to the
    first). The mean does not move; ``P`` gains ``G diag(var) Gᵀ`` with ``G`` the identity on
    the moved rows and on the block."""
    var = np.asarray(var, dtype=float)
    if var.shape != (STEP_SIZE,) or not np.all(np.isfinite(var)) or np.any(var < 0):
        raise ConfigError(f"a bias step needs {STEP_SIZE} finite variances >= 0, got {var}")
    m = as_clone_manifold(ukf.manifold)
    x, P = ukf.x, ukf.P
    T = np.eye(m.ndx)  # the old tangent in the new one, for a smoother (``UKF.resize``)
    if m.n_aux == 0:
        x, P, m = augment_aux(x, P, m, STEP_SIZE)
        assert m.aux is not None
        T = np.delete(np.eye(m.ndx), np.arange(m.ndx)[m.aux[1]], axis=1)
    elif m.n_aux != STEP_SIZE:
        raise ConfigError(f"the state's auxiliary block has {m.n_aux} numbers, not a step's")
    assert m.aux is not None
    var = np.maximum(var, STEP_FLOOR_REL * np.diag(P)[STEP_ROWS])
    G = np.zeros((m.ndx, STEP_SIZE))
    G[np.arange(m.ndx)[m.aux[1]], np.arange(STEP_SIZE)] = 1.0
    G[STEP_ROWS, np.arange(STEP_SIZE)] = 1.0
    ukf.resize(m, x, P + (G * var) @ G.T, T)


def step_rows(ukf: UKF) -> slice | None:
    """The step's columns in ``ukf.x`` (None: no step pending)."""
    m = ukf.manifold
    if isinstance(m, CloneManifold) and m.aux is not None:
        return m.aux[0]
    return None


def drop_step(ukf: UKF) -> None:
    """Marginalise the step (a confirmed step, or a filter declared lost): delete its rows."""
    m = ukf.manifold
    if not isinstance(m, CloneManifold) or m.aux is None:
        return
    T = np.delete(np.eye(m.ndx), np.arange(m.ndx)[m.aux[1]], axis=0)
    x, P, new = marginalize_aux(ukf.x, ukf.P, m)
    ukf.resize(new.nav if new.n_clones == 0 and new.n_calib == 0 else new, x, P, T)


def undo_step(ukf: UKF) -> UpdateStats | None:
    """A false alarm: condition the filter on ``n = 0`` (ungated; the decision is made), then
    drop the step. None when no step is pending."""
    m = ukf.manifold
    if not isinstance(m, CloneManifold) or m.aux is None:
        return None
    cols, rows = m.aux
    R = np.maximum(UNDO_NOISE_REL * np.diag(ukf.P)[rows], 1e-300)

    def h(X: F64) -> F64:
        return X[:, cols]

    (stats,) = ukf.update_blocks([(h, np.zeros(STEP_SIZE), R, None, "bias_undo")], None)
    drop_step(ukf)
    return stats


@dataclass
class BiasAlarm:
    """The biases before a bias alarm's widening: ``b`` (6,) gyro (rad/s) then accelerometer
    (m/s²), ``P`` (6, 6) their covariance; ``t_ns`` the alarm's time, ``confirm_ns`` when they
    are recalled at the latest."""

    t_ns: int
    confirm_ns: int
    b: F64
    P: F64

    @classmethod
    def before_widening(cls, ukf: UKF, t_ns: int, confirm_s: float) -> BiasAlarm:
        """Snapshot of ``ukf``'s biases (biased layout) at the alarm ``t_ns``."""
        i = _DX_BIAS
        return cls(int(t_ns), int(t_ns + confirm_s * 1e9), ukf.x[_X_BIAS].copy(),
                   ukf.P[np.ix_(i, i)].copy())  # fmt: skip


def _innovation(ukf: UKF, alarm: BiasAlarm, t_ns: int, random_walk_var: F64) -> tuple[F64, F64]:
    """``b₀`` against the state's biases: the residual (6,) and ``P₀ + Q_rw τ`` (6, 6)."""
    tau_s = max(0.0, (t_ns - alarm.t_ns) * 1e-9)
    R = alarm.P + np.diag(np.asarray(random_walk_var, dtype=float) * tau_s)
    return alarm.b - ukf.x[_X_BIAS], R


def bias_change_nis(ukf: UKF, alarm: BiasAlarm, t_ns: int, random_walk_var: F64) -> float:
    """How far the state's biases have moved from ``alarm``'s: ``rᵀ S⁻¹ r`` (chi-square,
    6 dof, when nothing stepped), with ``S`` the state's bias covariance plus the snapshot's
    ``P₀`` and the random walk ``Q_rw τ`` since the alarm (``random_walk_var`` (6,) per second:
    (rad/s)² s⁻¹ for the gyro, (m/s²)² s⁻¹ for the accelerometer). Reads the filter, changes
    nothing."""
    r, R = _innovation(ukf, alarm, t_ns, random_walk_var)
    S = ukf.P[np.ix_(_DX_BIAS, _DX_BIAS)] + R
    # pseudo-inverse: a bias known exactly (zero prior and random walk) tests nothing
    return float(r @ np.linalg.pinv(0.5 * (S + S.T), hermitian=True) @ r)
