"""Confirming a bias alarm (``navigation.bias_recall``): the step an alarm injects is kept as
states; a false alarm is undone exactly (conditioning on a zero step gives back the filter that
was never widened), a confirmed step is marginalised and leaves the widened filter alone."""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.models.clones import CloneManifold, augment_clone
from svains.models.manifold import NavManifold
from svains.models.state import BA, BIASED, DBA, DBG, P, V
from svains.navigation.bias_recall import (
    STEP_ROWS,
    STEP_SIZE,
    BiasAlarm,
    bias_change_nis,
    drop_step,
    inject_step,
    step_rows,
    undo_step,
)
from svains.navigation.fault_handling import step_variances

S = 1_000_000_000
BIAS_ROWS = np.r_[np.arange(DBG.start, DBG.stop), np.arange(DBA.start, DBA.stop)]
ND = BIASED.ndx


def _state(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A biased-layout state with a covariance in realistic proportions (biases known to 1e-3
    rad/s and 0.02 m/s², correlated with the rest)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=BIASED.nx) * 0.1
    x[6:10] = [1.0, 0.0, 0.0, 0.0]
    sd = np.r_[np.full(3, 0.5), np.full(3, 0.1), np.full(3, 0.01), np.full(3, 0.01),
               np.full(3, 1e-3), np.full(3, 0.02)]  # δp δv δθ δω δbg δba
    C = np.corrcoef(rng.normal(size=(ND, 4 * ND)))
    return x, 0.5 * C * np.outer(sd, sd) + 0.5 * np.diag(sd**2)


def _ukf(seed: int = 3) -> UKF:
    x, P_ = _state(seed)
    return UKF(NavManifold(BIASED), MerweScaledSigmaPoints(ND), x, P_)


def _ukf_with_two_clones() -> UKF:
    x, P_ = _state(7)
    m = CloneManifold(NavManifold(BIASED), 0)
    x, P_, m = augment_clone(x, P_, m)
    x[0:3] += [2.0, -1.0, 0.5]
    x, P_, m = augment_clone(x, P_, m)
    return UKF(m, MerweScaledSigmaPoints(m.ndx), x, P_)


def _step_var(ukf: UKF) -> np.ndarray:
    """Standard deviations x100, capped at 1 rad/s (gyro: not reached) and 1 m/s² (reached)."""
    return step_variances(ukf, 1e4, 1.0, 1.0, elapsed_s=1.0)


def _drive(ukf: UKF, z_ba_x: float) -> None:
    """Linear models only (so the sigma-point filter is exact): 2 s of constant velocity with
    process noise on the velocity, then a position fix and a measurement of the accelerometer
    bias's x axis (a stand-in for what GPS teaches the biases)."""

    def f(X: np.ndarray, u: object, dt: float) -> np.ndarray:
        out = X.copy()
        out[:, P] += dt * X[:, V]
        return out

    q = np.r_[np.zeros(3), np.full(3, 1e-3)]
    for z_p in (np.array([0.3, -0.2, 0.1]), np.array([0.5, -0.1, 0.2])):
        ukf.predict(f, None, 1.0, q)

        def h_p(X: np.ndarray) -> np.ndarray:
            return X[:, P]

        def h_b(X: np.ndarray) -> np.ndarray:
            return X[:, BA.start : BA.start + 1]

        ukf.update_blocks([(h_p, z_p, np.full(3, 0.04), None, "p"),
                           (h_b, np.array([z_ba_x]), np.array([1e-4]), None, "b")])  # fmt: skip


def test_a_step_is_added_to_the_moved_rows_and_kept_as_states() -> None:
    ukf = _ukf_with_two_clones()
    m0 = ukf.manifold
    assert isinstance(m0, CloneManifold)
    x0, P0 = ukf.x.copy(), ukf.P.copy()
    var = _step_var(ukf)
    inject_step(ukf, var)
    m = ukf.manifold
    assert isinstance(m, CloneManifold) and m.n_aux == STEP_SIZE and m.n_clones == 2
    assert m.aux is not None
    a = np.arange(m.ndx)[m.aux[1]]
    old = np.r_[0 : a[0], a[-1] + 1 : m.ndx]  # the old tangent rows in the new state
    expected = P0.copy()
    expected[STEP_ROWS, STEP_ROWS] += var
    np.testing.assert_allclose(ukf.P[np.ix_(old, old)], expected)
    np.testing.assert_allclose(ukf.P[np.ix_(a, a)], np.diag(var))
    np.testing.assert_allclose(ukf.P[np.ix_(STEP_ROWS, a)], np.diag(var))
    np.testing.assert_array_equal(ukf.x[step_rows(ukf)], 0.0)
    for i in range(2):  # the clones are where they were, only further along x
        for new_cols, old_cols in zip(m.columns(i), m0.columns(i), strict=True):
            np.testing.assert_array_equal(ukf.x[new_cols], x0[old_cols])
    # the gyro bias's standard deviation grew 100x, the accelerometer's 50x to its 1 m/s² cap
    sd = np.sqrt(np.diag(ukf.P))
    np.testing.assert_allclose(sd[DBG], 100.0 * np.sqrt(np.diag(P0)[DBG]))
    np.testing.assert_allclose(sd[DBA], 1.0)
    inject_step(ukf, var)  # a second alarm adds to the same block
    assert ukf.manifold.ndx == m.ndx
    np.testing.assert_allclose(ukf.P[np.ix_(a, a)], 2.0 * np.diag(var))
    assert np.linalg.eigvalsh(ukf.P).min() > 0.0
    with pytest.raises(ConfigError, match="12 finite variances"):
        inject_step(ukf, np.full(6, 1.0))


def test_a_false_alarm_is_undone_exactly() -> None:
    ref, ukf = _ukf(), _ukf()
    inject_step(ukf, _step_var(ukf))
    _drive(ref, 0.03)
    _drive(ukf, 0.03)
    # widened, the filter took the bias measurement much more to heart
    assert abs(ukf.x[BA.start] - ref.x[BA.start]) > 1e-3
    stats = undo_step(ukf)
    assert stats is not None and stats.accepted and stats.dof == STEP_SIZE
    assert step_rows(ukf) is None and isinstance(ukf.manifold, NavManifold)
    # conditioned on a zero step, it is the filter that was never widened
    np.testing.assert_allclose(ukf.x, ref.x, atol=1e-7)
    np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-5, atol=1e-12)


def test_a_confirmed_step_is_marginalised_and_its_learning_kept() -> None:
    ukf = _ukf()
    inject_step(ukf, _step_var(ukf))
    _drive(ukf, 0.5)  # a 0.5 m/s² step on the accelerometer's x axis
    x, P_ = ukf.x.copy(), ukf.P.copy()
    m = ukf.manifold
    assert isinstance(m, CloneManifold) and m.aux is not None
    keep = np.r_[0 : m.aux[1].start, m.aux[1].stop : m.ndx]
    drop_step(ukf)
    assert isinstance(ukf.manifold, NavManifold)
    np.testing.assert_array_equal(ukf.x, np.r_[x[: m.aux[0].start], x[m.aux[0].stop :]])
    np.testing.assert_array_equal(ukf.P, P_[np.ix_(keep, keep)])
    assert ukf.x[BA.start] > 0.45  # the step was learnt, not pulled back
    drop_step(ukf)  # nothing pending: nothing changes
    assert undo_step(ukf) is None
    np.testing.assert_array_equal(ukf.x, np.r_[x[: m.aux[0].start], x[m.aux[0].stop :]])


def test_the_confirmation_test_sees_a_step_and_allows_the_random_walk() -> None:
    # A bias that drifted by its random walk over a long wait is no step: with the walk's
    # variance added (4 s of 0.01 (m/s²)² / s: 0.2 m/s²) a 0.3 m/s² move stays inside the
    # 0.999 gate (6 dof: 22.5) that the snapshot's own 0.02 m/s² leaves far behind.
    ukf = _ukf()
    alarm = BiasAlarm.before_widening(ukf, 0, confirm_s=4.0)
    assert alarm.confirm_ns == 4 * S
    assert bias_change_nis(ukf, alarm, 4 * S, np.zeros(6)) == 0.0
    x = ukf.x.copy()
    x[BA.start] += 0.3
    Pm = ukf.P.copy()
    Pm[np.ix_(BIAS_ROWS, BIAS_ROWS)] *= 1e-4  # learnt well since the alarm
    ukf.x, ukf.P = x, Pm
    rw = np.r_[np.zeros(3), np.full(3, 0.01)]
    assert bias_change_nis(ukf, alarm, 4 * S, rw) < 22.5
    assert bias_change_nis(ukf, alarm, 4 * S, np.zeros(6)) > 100.0


def test_biases_known_exactly_test_nothing_and_raise_nothing() -> None:
    # A configuration with zero bias prior and random walk: S is singular on the biases.
    ukf = _ukf()
    alarm = BiasAlarm.before_widening(ukf, 0, confirm_s=4.0)
    alarm.P[:] = 0.0
    P_ = ukf.P.copy()
    P_[np.ix_(BIAS_ROWS, BIAS_ROWS)] = 0.0
    P_[np.ix_(BIAS_ROWS, np.arange(P_.shape[0]))] = 0.0
    P_[np.ix_(np.arange(P_.shape[0]), BIAS_ROWS)] = 0.0
    ukf.P = P_
    assert bias_change_nis(ukf, alarm, 1 * S, np.zeros(6)) == 0.0
