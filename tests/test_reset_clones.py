"""A GPS reset of a lost filter moves the pose clones with the position, and an inflation scales
them with the current pose (fault handling)."""

from __future__ import annotations

import numpy as np
import pytest

from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.models.clones import CLONE_JITTER, CLONE_JITTER_REL, CloneManifold, augment_clone
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, DBA, DBG, DP, DTH, DV, DW, PAPER, StateLayout
from svains.navigation.consistency import RecoveryAction
from svains.navigation.fault_handling import RateLimitedLog, Recovery, inflate, widen_biases
from svains.navigation.options import FaultOptions
from svains.sensors.types import GpsCalib


def _random_state(layout: StateLayout, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random state (unit quaternion) and a random positive-definite covariance."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=layout.nx)
    x[6:10] /= np.linalg.norm(x[6:10])
    A = rng.normal(size=(layout.ndx, layout.ndx)) * 0.1
    return x, A @ A.T + 1e-3 * np.eye(layout.ndx)


def _ukf_with_two_clones() -> UKF:
    x, P = _random_state(BIASED, 7)
    m = CloneManifold(NavManifold(BIASED), 0)
    x, P, m = augment_clone(x, P, m)
    x[0:3] += [2.0, -1.0, 0.5]  # the body moved on after the first clone
    x, P, m = augment_clone(x, P, m)
    x[0:3] += [1.0, 0.5, 0.0]
    return UKF(m, MerweScaledSigmaPoints(m.ndx), x, P)


def test_reset_shifts_clones_keeps_relative_motion_and_correlates_their_errors() -> None:
    ukf = _ukf_with_two_clones()
    m = ukf.manifold
    before = ukf.x.copy()
    cal = GpsCalib(np.zeros(3), 1.0, 0.5, 0.1)
    rec = Recovery(FaultOptions(), RateLimitedLog(1.0))
    p_fix = before[0:3] + np.array([30.0, -40.0, 5.0])  # the filter was 50 m off
    rec.reset_from_gps(ukf, cal, p_fix, None)
    np.testing.assert_allclose(ukf.x[0:3], p_fix)
    for i in range(2):
        cp, cq = m.columns(i)
        # The motion since each clone is what it was; the clone attitude is untouched.
        np.testing.assert_allclose(ukf.x[0:3] - ukf.x[cp], before[0:3] - before[cp], atol=1e-12)
        np.testing.assert_array_equal(ukf.x[cq], before[cq])
        t = m.tangent(i)
        r = np.arange(t.start, t.start + 3)
        dp = np.arange(ukf.P.shape[0])[DP]
        jitter = np.maximum(CLONE_JITTER, CLONE_JITTER_REL * 0.25)
        np.testing.assert_allclose(ukf.P[np.ix_(r, r)], (0.25 + jitter) * np.eye(3), rtol=1e-15)
        np.testing.assert_allclose(ukf.P[np.ix_(r, dp)], 0.25 * np.eye(3))
    np.testing.assert_allclose(ukf.P, ukf.P.T)
    assert np.linalg.eigvalsh(ukf.P).min() > 0.0  # the sigma points still have a factor
    assert not rec.reset_pending


@pytest.mark.parametrize("std_m", [123.4, 77.7, 250.1, 1000.3])
def test_a_reset_to_a_coarse_fix_leaves_a_covariance_with_a_plain_cholesky_factor(
    std_m: float,
) -> None:
    # Every clone's position error copies the new one's (variance std_m² ~ 1e4): the jitter
    # must be relative to that variance, an absolute 1e-12 is below its rounding.
    ukf = _ukf_with_two_clones()
    cal = GpsCalib(np.zeros(3), 1.0, std_m, 0.1)
    rec = Recovery(FaultOptions(), RateLimitedLog(1.0))
    rec.reset_from_gps(ukf, cal, ukf.x[0:3] + 30.0, None)
    L = np.linalg.cholesky(ukf.P)  # no repair needed
    assert np.all(np.diag(L) > 0.0)
    ukf.predict(lambda X, u, dt: X, None, 0.1, np.zeros(3))  # the sigma points draw


def test_inflation_scales_the_biases_and_the_clones_with_the_current_pose() -> None:
    # The clones are past poses of the same lost filter: left small, the next vision update
    # would pin the inflated position back onto a wrong clone. The biases: after a bias step
    # a filter sure of the old bias would drift off again after every recovery.
    ukf = _ukf_with_two_clones()
    m = ukf.manifold
    before = ukf.P.copy()
    inflate(ukf, RecoveryAction("inflate", "test", ("gps",), inflate_factor=100.0))
    clones = np.concatenate([np.arange(m.tangent(i).start, m.tangent(i).stop) for i in range(2)])
    biases = np.arange(DBG.start, DBA.stop)
    scaled = np.concatenate([np.arange(9), biases, clones])
    rest = np.setdiff1d(np.arange(before.shape[0]), scaled)
    np.testing.assert_allclose(
        ukf.P[np.ix_(scaled, scaled)], 100.0 * before[np.ix_(scaled, scaled)]
    )
    np.testing.assert_allclose(ukf.P[np.ix_(rest, rest)], before[np.ix_(rest, rest)])
    np.testing.assert_allclose(ukf.P[np.ix_(scaled, rest)], 10.0 * before[np.ix_(scaled, rest)])
    assert np.linalg.eigvalsh(ukf.P).min() > 0.0


def test_inflation_of_the_paper_state_scales_the_pose_only() -> None:
    x, P = _random_state(PAPER, 8)
    ukf = UKF(NavManifold(PAPER), MerweScaledSigmaPoints(PAPER.ndx), x, P)
    inflate(ukf, RecoveryAction("inflate", "test", ("gps",), inflate_factor=4.0))
    np.testing.assert_allclose(ukf.P[:9, :9], 4.0 * P[:9, :9])
    np.testing.assert_allclose(ukf.P[DW, DW], P[DW, DW])  # no bias blocks: ω is left alone
    np.testing.assert_allclose(ukf.P[:9, DW], 2.0 * P[:9, DW])


def test_a_bias_alarm_widens_the_biases_up_to_their_caps_and_the_motion_they_drove() -> None:
    ukf = _ukf_with_two_clones()
    P = ukf.P.copy()
    sd = np.sqrt(np.diag(P))
    # caps: the gyro's above sd * 100 on every axis, the accelerometer's below sd on x
    cap_g, cap_a = 1e3, 0.5 * sd[DBA.start]
    widen_biases(ukf, 1e4, cap_g, cap_a, elapsed_s=2.0)
    d = np.ones(P.shape[0])
    d[DBG] = 100.0
    d[DBA] = np.maximum(np.minimum(100.0 * sd[DBA], cap_a) / sd[DBA], 1.0)
    assert d[DBA.start] == 1.0  # capped below its own std: left alone, not shrunk
    expected = P * np.outer(d, d)  # correlations kept
    # what the added bias spread would have done over 2 s: on attitude and velocity only
    i = np.arange(P.shape[0])
    expected[i[DTH], i[DTH]] += (sd[DBG] * np.sqrt(100.0**2 - 1.0) * 2.0) ** 2
    expected[i[DV], i[DV]] += (sd[DBA] * np.sqrt(d[DBA] ** 2 - 1.0) * 2.0) ** 2
    np.testing.assert_allclose(ukf.P, expected)
    assert np.linalg.eigvalsh(ukf.P).min() > 0.0
    x, Pp = _random_state(PAPER, 8)
    paper = UKF(NavManifold(PAPER), MerweScaledSigmaPoints(PAPER.ndx), x, Pp)
    widen_biases(paper, 1e4, 1.0, 1.0)  # no bias states: nothing changes
    np.testing.assert_array_equal(paper.P, Pp)
