"""Confirming a bias alarm: the biases from before it, recalled as a measurement.

A bias alarm (``ConsistencyMonitor.biased``) widens the IMU biases so that the next fixes can
move them (``fault_handling.widen_biases``): the filter forgets what it knew of them. On a
false alarm (1 % of windows at the 0.99 quantile on white innovations) that knowledge was
right, and without it a GPS outage soon after is crossed on biases learnt from two or three
fixes (a simulated ``ins`` outage: 2.36 m → 22.5 m).

So the alarm keeps the biases' mean ``b₀`` (6,) and covariance ``P₀`` (6, 6) from just before
the widening (:class:`BiasAlarm`) and tests, after every group of updates, whether the biases
learnt since have left them: ``r = b − b₀`` against ``S = P_b + P₀ + Q_rw τ`` (the random walk
over the τ since the alarm), :func:`bias_change_nis`.

- Beyond the ``probability`` quantile (6 dof): the step is confirmed; the widened filter goes
  on.
- Still inside it when the GPS falls silent (an outage, where nothing can confirm a step) or
  ``confirm_s`` after the alarm: no step happened. ``b₀`` is given back to the filter as a
  measurement of its own biases, ``z = b₀``, ``R = P₀ + Q_rw τ`` (:func:`recall_biases`); the
  update also pulls velocity and attitude back through their correlation with the biases.

Treating ``b₀`` as independent of the current state counts the pre-alarm data twice where the
widening kept the biases' correlations; the measured effect is in ``FaultOptions``' docstring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import UKF, UpdateStats
from svains.models.state import BA, BG, DBA, DBG

F64 = NDArray[np.float64]
_X_BIAS = np.r_[np.arange(BG.start, BG.stop), np.arange(BA.start, BA.stop)]  # x columns
_DX_BIAS = np.r_[np.arange(DBG.start, DBG.stop), np.arange(DBA.start, DBA.stop)]  # tangent rows


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
    """``b₀`` against the state's biases: the residual (6,) and ``R = P₀ + Q_rw τ`` (6, 6)."""
    tau_s = max(0.0, (t_ns - alarm.t_ns) * 1e-9)
    R = alarm.P + np.diag(np.asarray(random_walk_var, dtype=float) * tau_s)
    return alarm.b - ukf.x[_X_BIAS], R


def bias_change_nis(ukf: UKF, alarm: BiasAlarm, t_ns: int, random_walk_var: F64) -> float:
    """How far the state's biases have moved from ``alarm``'s: ``rᵀ S⁻¹ r`` (chi-square,
    6 dof, when nothing stepped), with ``S`` the state's bias covariance plus ``R`` (see
    :func:`recall_biases`). Reads the filter, changes nothing."""
    r, R = _innovation(ukf, alarm, t_ns, random_walk_var)
    S = ukf.P[np.ix_(_DX_BIAS, _DX_BIAS)] + R
    # pseudo-inverse: a bias known exactly (zero prior and random walk) tests nothing
    return float(r @ np.linalg.pinv(0.5 * (S + S.T), hermitian=True) @ r)


def recall_biases(ukf: UKF, alarm: BiasAlarm, t_ns: int, random_walk_var: F64,
                  probability: float | None = None) -> UpdateStats:  # fmt: skip
    """Fuse ``alarm``'s biases as a measurement of the state's (see the module), gated at the
    ``probability`` chi-square quantile (6 dof; None: ungated, when :func:`bias_change_nis`
    has already decided: ``h`` is linear, so the two tests are the same). ``random_walk_var``
    (6,): the biases' random walk variance per second ((rad/s)² s⁻¹ for the gyro, (m/s²)² s⁻¹
    for the accelerometer).
    Accepted: no step (the biases are restored); rejected: the step is confirmed."""
    _, R = _innovation(ukf, alarm, t_ns, random_walk_var)

    def h(X: F64) -> F64:
        return X[:, _X_BIAS]

    (stats,) = ukf.update_blocks([(h, alarm.b, R, None, "bias_recall")], probability)
    return stats
