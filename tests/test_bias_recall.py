"""Confirming a bias alarm (``navigation.bias_recall``): the biases from before the widening,
recalled as a measurement, restore them after a false alarm and leave a real step alone."""

from __future__ import annotations

import numpy as np

from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.models.manifold import NavManifold
from svains.models.state import BA, BIASED, DBA, DBG
from svains.navigation.bias_recall import BiasAlarm, bias_change_nis, recall_biases
from svains.navigation.fault_handling import widen_biases

S = 1_000_000_000
BIAS_ROWS = np.r_[np.arange(DBG.start, DBG.stop), np.arange(DBA.start, DBA.stop)]


def _ukf(seed: int = 3) -> UKF:
    """A biased-layout filter with a random state and a covariance in realistic proportions
    (biases known to 1e-3 rad/s and 0.02 m/s², correlated with the rest)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=BIASED.nx) * 0.1
    x[6:10] = [1.0, 0.0, 0.0, 0.0]
    sd = np.r_[np.full(3, 0.5), np.full(3, 0.1), np.full(3, 0.01), np.full(3, 0.01),
               np.full(3, 1e-3), np.full(3, 0.02)]  # δp δv δθ δω δbg δba
    C = np.corrcoef(rng.normal(size=(BIASED.ndx, 4 * BIASED.ndx)))
    P = 0.5 * C * np.outer(sd, sd) + 0.5 * np.diag(sd**2)
    return UKF(NavManifold(BIASED), MerweScaledSigmaPoints(BIASED.ndx), x, P)


def _bias_block(ukf: UKF) -> np.ndarray:
    return ukf.P[np.ix_(BIAS_ROWS, BIAS_ROWS)]


def _shrunk_biases(P: np.ndarray) -> np.ndarray:
    """``P`` with the biases' standard deviations (and their cross terms) divided by 100."""
    d = np.ones(P.shape[0])
    d[BIAS_ROWS] = 0.01
    return P * np.outer(d, d)


def test_a_false_alarm_gets_its_biases_back() -> None:
    ukf = _ukf()
    before = _bias_block(ukf).copy()
    x_before = ukf.x.copy()
    alarm = BiasAlarm.before_widening(ukf, 10 * S, confirm_s=4.0)
    assert alarm.confirm_ns == 14 * S
    widen_biases(ukf, 1e4, 0.05, 1.0, elapsed_s=1.0)
    assert np.all(np.diag(_bias_block(ukf)) > 50 * np.diag(before))
    stats = recall_biases(ukf, alarm, 14 * S, np.zeros(6), 0.999)
    assert stats.accepted and stats.dof == 6 and stats.nis < 1e-6  # nothing moved
    # the widening forgot the biases; the recall gives them back (to within the prior the
    # widened filter still adds, 1e-4 of it) and leaves the mean where it was
    np.testing.assert_allclose(np.diag(_bias_block(ukf)), np.diag(before), rtol=2e-3)
    np.testing.assert_allclose(ukf.x, x_before, atol=1e-12)


def test_a_confirmed_step_leaves_the_widened_filter_alone() -> None:
    ukf = _ukf()
    alarm = BiasAlarm.before_widening(ukf, 10 * S, confirm_s=4.0)
    widen_biases(ukf, 1e4, 0.05, 1.0, elapsed_s=1.0)
    # the fixes since the alarm learnt a 0.5 m/s² step on the accelerometer's x axis
    x = ukf.x.copy()
    x[BA.start] += 0.5
    P = _shrunk_biases(ukf.P)  # and learnt it well
    ukf.x, ukf.P = x, P
    stats = recall_biases(ukf, alarm, 14 * S, np.zeros(6), 0.999)
    assert not stats.accepted and stats.nis > 20 * stats.gate  # measured 506 > 22.5
    np.testing.assert_array_equal(ukf.x, x)
    np.testing.assert_array_equal(ukf.P, P)


def test_the_random_walk_since_the_alarm_widens_what_is_recalled() -> None:
    # A bias that drifted by its random walk over a long wait is no step: with the walk's
    # variance added (4 s of 0.01 (m/s²)² / s: 0.2 m/s²) the recall accepts a 0.3 m/s² move
    # that the snapshot's own 0.02 m/s² refuses.
    def moved() -> tuple[UKF, BiasAlarm]:
        ukf = _ukf()
        alarm = BiasAlarm.before_widening(ukf, 0, confirm_s=4.0)
        widen_biases(ukf, 1e4, 0.05, 1.0)
        x = ukf.x.copy()
        x[BA.start] += 0.3
        ukf.x, ukf.P = x, _shrunk_biases(ukf.P)  # learnt since the alarm
        return ukf, alarm

    rw = np.r_[np.zeros(3), np.full(3, 0.01)]
    ukf, alarm = moved()
    assert recall_biases(ukf, alarm, 4 * S, rw, 0.999).accepted
    ukf, alarm = moved()
    assert not recall_biases(ukf, alarm, 4 * S, np.zeros(6), 0.999).accepted


def test_biases_known_exactly_test_nothing_and_raise_nothing() -> None:
    # A configuration with zero bias prior and random walk: S is singular on the biases.
    ukf = _ukf()
    alarm = BiasAlarm.before_widening(ukf, 0, confirm_s=4.0)
    alarm.P[:] = 0.0
    P = ukf.P.copy()
    P[np.ix_(BIAS_ROWS, BIAS_ROWS)] = 0.0
    P[np.ix_(BIAS_ROWS, np.arange(P.shape[0]))] = 0.0
    P[np.ix_(np.arange(P.shape[0]), BIAS_ROWS)] = 0.0
    ukf.P = P
    assert bias_change_nis(ukf, alarm, 1 * S, np.zeros(6)) == 0.0
