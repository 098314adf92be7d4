"""The bank of headings for an INS started in motion with no heading (``navigation.yaw_bank``):
its weights are Bayes' rule over the copies, its merge the mixture's moments, and on simulated
flights too slow for the course it finds the heading in a turn and stays honest without one."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from _flights import gps_flight
from svains.datasets import load_dataset
from svains.errors import FilterError
from svains.evaluation.run import run_method
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.geometry.rotation import quat_exp, quat_to_rotmat
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, DP, DTH, Q
from svains.models.state import P as POS
from svains.navigation.base import MeasurementBlock
from svains.navigation.heading_check import yaw_std
from svains.navigation.init import HEADING_BANK
from svains.navigation.options import InitOptions, ReplayOptions, RunConfig
from svains.navigation.yaw_bank import YawBank, bank_yaw, level_axis

UP = np.array([0.0, 0.0, 1.0])


class _StillIns:
    """An INS filter's stand-in: a UKF on the navigation state that nothing propagates."""

    def __init__(self, x: np.ndarray, P: np.ndarray) -> None:
        m = NavManifold(BIASED)
        self.ukf = UKF(m, MerweScaledSigmaPoints(m.ndx), x, P)

    def propagate_to(self, t_ns: int) -> None:
        pass


def _bank(n: int = 4, f_W: np.ndarray = 9.81 * UP) -> YawBank:
    x = np.zeros(BIASED.nx)
    x[Q] = (1.0, 0.0, 0.0, 0.0)
    x[3:6] = (2.0, 0.0, 0.0)  # moving along world x
    P = np.diag(np.full(BIASED.ndx, 0.01))
    return YawBank(_StillIns(x, P), UP, f_W, np.array([0.5, 0.0, 0.0]), n, math.radians(15.0))


def _velocity_block(v_W: np.ndarray, std: float) -> MeasurementBlock:
    def h(X: np.ndarray) -> np.ndarray:
        return X[:, 3:6]

    return MeasurementBlock("gps", h, np.asarray(v_W, float), np.full(3, std**2))


def test_the_copies_split_the_circle_about_the_antenna_with_a_yaw_sigma_of_a_sector() -> None:
    bank = _bank(4)
    yaws = [bank_yaw(m.ukf.x, UP, 0) for m in bank.members]
    np.testing.assert_allclose(np.unwrap(yaws) - yaws[0], np.arange(4) * math.pi / 2, atol=1e-12)
    for m in bank.members:
        # the antenna (0.5 m ahead of the body) stays where the start put it
        p_A = m.ukf.x[POS] + quat_to_rotmat(m.ukf.x[Q]) @ np.array([0.5, 0.0, 0.0])
        np.testing.assert_allclose(p_A, [0.5, 0.0, 0.0], atol=1e-12)
        assert yaw_std(m.ukf, UP) == pytest.approx(math.pi / 4)
        # only the yaw's variance changed
        np.testing.assert_allclose(np.diag(m.ukf.P)[DP], 0.01)
    assert np.exp(bank.log_w).sum() == pytest.approx(1.0)


def test_the_weights_are_bayes_rule_over_the_copies_predicted_innovations() -> None:
    """Each copy's weight times the likelihood of the fix under its own predicted innovation
    (mean and covariance from its sigma points), normalised; the copies' means then moved."""
    bank = _bank(4)
    for m, dv in zip(bank.members, ([0.0, 0.1, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0],
                                    [-0.2, 0.2, 0.0]), strict=True):  # fmt: skip
        m.ukf.x[3:6] += dv
    z = np.array([2.05, 0.02, 0.0])
    block = _velocity_block(z, 0.1)
    prior = [(m.ukf.x[3:6].copy(), m.ukf.P[3:6, 3:6] + 0.01 * np.eye(3)) for m in bank.members]
    like = np.array([multivariate_normal(mu, S).pdf(z) for mu, S in prior])
    stats = bank.update(block, None, 10**9)
    expected = like / like.sum()
    np.testing.assert_allclose(np.exp(bank.log_w), expected, rtol=1e-6)
    assert stats is not None and stats.name == "gps" and bank.fixes == 1
    heaviest = bank.members[int(np.argmax(expected))]
    assert np.linalg.norm(heaviest.ukf.x[3:6] - z) < np.linalg.norm(prior[0][0] - z)


def test_a_fix_every_copy_refuses_weighs_none_and_is_fused_by_none() -> None:
    bank = _bank(4)
    before = [m.ukf.x.copy() for m in bank.members]
    stats = bank.update(_velocity_block(np.array([40.0, 0.0, 0.0]), 0.1), 0.999, 10**9)
    assert stats is not None and not stats.accepted  # recorded as a refusal
    np.testing.assert_allclose(np.exp(bank.log_w), 0.25)
    for m, x in zip(bank.members, before, strict=True):
        np.testing.assert_array_equal(m.ukf.x, x)
    assert bank.fixes == 0


def test_an_accelerating_start_turns_its_copies_about_its_specific_force() -> None:
    """The start levels its attitude on the specific force its first fixes imply (``R f_B =
    f_W``); copies turned about the vertical broke that for all but the first whenever the
    start accelerated, and a review's KITTI raw start merged 80° off. Turned about ``f_W``,
    every copy keeps it, and their headings still split the circle."""
    f_W = np.array([3.0, -1.0, 9.81])  # 3.2 m/s² sideways
    bank = _bank(8, f_W)
    f_B = f_W  # the start's attitude is the identity
    for m in bank.members:
        np.testing.assert_allclose(quat_to_rotmat(m.ukf.x[Q]) @ f_B, f_W, atol=1e-12)
    yaws = np.sort(np.mod([bank_yaw(m.ukf.x, UP, 0) for m in bank.members], 2 * math.pi))
    assert np.all(np.diff(yaws) > math.radians(30.0))
    # each copy's heading variance is about the turn's axis, the tilt keeps its own
    u = quat_to_rotmat(bank.members[3].ukf.x[Q]).T @ (f_W / np.linalg.norm(f_W))
    P_att = bank.members[3].ukf.P[DTH, DTH]
    assert float(u @ P_att @ u) == pytest.approx((math.pi / 8) ** 2)
    e = np.cross(u, [0.0, 1.0, 0.0])
    e /= np.linalg.norm(e)
    assert float(e @ P_att @ e) == pytest.approx(0.01)


def test_a_copy_that_refuses_a_fix_keeps_its_mean_and_loses_the_gates_worth() -> None:
    """A fix one copy explains and the others find 30σ off: ungated, it was fused into every
    copy (the true one pulled halfway to it); gated, the others keep their means and each
    loses at most the gate's chi-square (a review)."""
    bank = _bank(4)
    bank.members[1].ukf.x[3:6] = (2.0, 3.0, 0.0)
    before = [m.ukf.x.copy() for m in bank.members]
    bank.update(_velocity_block(np.array([2.0, 3.0, 0.0]), 0.1), 0.999, 10**9)
    for i in (0, 2, 3):
        np.testing.assert_array_equal(bank.members[i].ukf.x, before[i])
    w = np.exp(bank.log_w)
    # the copies share the velocity covariance (one S); copy 1 predicted the fix exactly (NIS
    # 0), copy 0 is 30σ off and loses the gate's chi-square only
    assert w[1] / w[0] == pytest.approx(np.exp(0.5 * chi2.ppf(0.999, 3)), rel=1e-6)


def test_fixes_faster_than_one_a_second_weigh_as_one_a_second() -> None:
    """A 10 Hz receiver's fixes share their errors: counted as independent they merged a
    review's flight 39° off, sure to 11°. A fix 0.1 s after the last one weighed moves the
    log-weights a tenth as far; a range (no heading in it) moves none."""
    full, fast = _bank(4), _bank(4)
    for b in (full, fast):
        b.members[1].ukf.x[3:6] += (0.0, 0.3, 0.0)
        b.update(_velocity_block(np.array([2.0, 0.0, 0.0]), 0.1), None, 10**9)
    before = fast.log_w.copy()
    z = np.array([2.0, 0.05, 0.0])
    full.update(_velocity_block(z, 0.1), None, 3 * 10**9)
    ref = full.log_w.copy()
    fast.update(_velocity_block(z, 0.1), None, 10**9 + 10**8)
    # (both renormalised: compare differences against copy 0)
    np.testing.assert_allclose(fast.log_w - fast.log_w[0] - (before - before[0]),
                               0.1 * (ref - ref[0] - (before - before[0])), atol=0.02)  # fmt: skip
    block = _velocity_block(z, 0.1)
    sonar = MeasurementBlock("sonar", block.h, block.z, block.R)
    w = fast.log_w.copy()
    fast.update(sonar, None, 5 * 10**9)
    np.testing.assert_array_equal(fast.log_w, w)


def test_the_merge_is_the_mixtures_moments_and_waits_for_a_sure_heading() -> None:
    bank = _bank(8)
    assert bank.merged() is None  # no fix yet
    # two neighbouring copies hold the weight, each already sure of its heading
    for m in bank.members:
        m.ukf.P[DTH, DTH] = np.diag([1e-4, 1e-4, math.radians(3.0) ** 2])
    bank.members[1].ukf.x[POS] = bank.members[0].ukf.x[POS] + (0.1, 0.0, 0.0)
    bank.fixes = 1
    bank.log_w[:] = -np.inf
    bank.log_w[[0, 1]] = np.log([0.75, 0.25])
    # 45° apart: the mixture's heading is not known to 15°
    assert bank.heading()[1] > math.radians(15.0) and bank.merged() is None
    x1 = bank.members[1].ukf.x
    x1[Q] = bank.members[0].ukf.x[Q]  # now the two agree on the heading
    _, std = bank.heading()
    assert std == pytest.approx(math.radians(3.0), rel=1e-6)
    merged = bank.merged()
    assert merged is not None and merged.std_rad == pytest.approx(std)
    d = np.zeros(BIASED.ndx)
    d[DP] = (0.1, 0.0, 0.0)  # copy 1 from copy 0 on the tangent space
    np.testing.assert_allclose(merged.x[POS], bank.members[0].ukf.x[POS] + 0.25 * d[DP])
    P_expected = (0.75 * bank.members[0].ukf.P + 0.25 * bank.members[1].ukf.P
                  + 0.75 * 0.25 * np.outer(d, d))  # fmt: skip
    np.testing.assert_allclose(merged.P, P_expected, atol=1e-15)
    # about the heaviest copy: no mean taken out, its covariance is wider along the offset
    x_h, P_h = bank.about_heaviest()
    np.testing.assert_array_equal(x_h, bank.members[0].ukf.x)
    np.testing.assert_allclose(P_h - merged.P, 0.25**2 * np.outer(d, d), atol=1e-15)


def test_the_merge_matches_a_sampled_mixture_of_turned_copies() -> None:
    """Two copies 40° apart with anisotropic tilt covariances, equal weights: the merge's
    mean and covariance match 200k samples of the mixture taken into the heaviest copy's chart
    (a body-frame error of copy i is ``J_r⁻¹(d_i) δ`` there: turned by ``R_refᵀ R_i`` instead,
    its tilt σ were 10-20 % off, a review)."""
    bank = _bank(2)
    m0, m1 = (m.ukf for m in bank.members)
    m1.x[Q] = quat_exp(np.radians([0.0, 0.0, 40.0]))
    m1.x[POS] = m0.x[POS] + (0.3, -0.2, 0.0)
    for m, tilt in ((m0, (0.15, 0.03)), (m1, (0.03, 0.15))):
        m.P[DTH, DTH] = np.diag([tilt[0] ** 2, tilt[1] ** 2, math.radians(4.0) ** 2])
    bank.fixes = 1
    bank.log_w[:] = np.log([0.5 + 1e-9, 0.5 - 1e-9])
    bank._max_std = math.pi  # (merge whatever the spread: the moments are what is tested)
    merged = bank.merged()
    assert merged is not None
    rng = np.random.default_rng(5)
    man = m0.manifold
    ys = []
    for m, n in ((m0, 100_000), (m1, 100_000)):
        e = rng.multivariate_normal(np.zeros(m.P.shape[0]), m.P, size=n)
        X = man.retract(np.broadcast_to(m.x, (n, m.x.size)), e)
        ys.append(man.local(X, m0.x))
    y = np.concatenate(ys)
    mean = y.mean(axis=0)
    np.testing.assert_allclose(man.local(merged.x[None, :], m0.x)[0], mean, atol=2e-3)
    cov = np.cov(y.T)
    # the merged covariance is about the merged mean, in its chart: close to the samples'
    att = slice(DTH.start, DTH.stop)
    np.testing.assert_allclose(np.sqrt(np.diag(merged.P)[att]), np.sqrt(np.diag(cov)[att]),
                               rtol=0.03)  # fmt: skip
    np.testing.assert_allclose(merged.P[DP, DP], cov[DP, DP], rtol=0.03, atol=1e-4)


def test_a_bank_whose_copies_all_fail_says_so() -> None:
    bank = _bank(3)
    for m in bank.members:
        def fail(t_ns: int) -> None:
            raise FilterError("non-finite sigma points")
        m.propagate_to = fail  # type: ignore[method-assign]
    bank.propagate(10**9)
    assert not bank.alive


def test_the_level_axis_is_the_body_axis_nearest_the_horizontal() -> None:
    x = np.zeros(BIASED.nx)
    x[Q] = (math.cos(0.6), 0.0, math.sin(0.6), 0.0)  # pitched 69° about y: x points up-ish
    assert level_axis(x, UP) == 1


@pytest.fixture(scope="module")
def slow_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The village at 2 m/s (below the course's 3 m/s), 52 s, GPS throughout: straight along
    +y from 18 s, a 90° left turn at 34-38 s, then straight along -x."""
    return gps_flight(tmp_path_factory.mktemp("yaw_bank") / "slow", 52.0, 3)


def _ins(ds: object, start_s: float, models: int | None) -> dict:
    config = RunConfig(method="ins", init=InitOptions(mode="gps", yaw_bank_models=models),
                       use_mag=False, replay=ReplayOptions(start_s=start_s))  # fmt: skip
    return run_method(ds, "ins", config).report  # type: ignore[arg-type]


def test_an_ins_started_slowly_without_a_heading_finds_it_in_the_turn(slow_flight: Path) -> None:
    """From 30 s, heading 90° from the start's stand-in: the single arbitrary heading was
    collapsed by the first fixes and stayed wrong (measured yaw NEES 11.2, NEES 18.7); the
    bank finds the heading in the turn (yaw NEES 0.35, NEES 7.4)."""
    ds = load_dataset(slow_flight)
    rep = _ins(ds, 30.0, 8)
    init = rep["init"]
    assert init["heading"] == HEADING_BANK
    assert init["heading_source"].startswith("a bank of 8 headings")
    assert 4.0 < init["heading_found_s"] < 9.0 and init["heading_std_deg"] < 15.0
    old = _ins(ds, 30.0, None)
    assert "heading_source" not in old["init"]
    assert rep["nees_mean"] < 12.0 < old["nees_mean"]
    assert rep["nees_blocks"]["yaw"] < 3.0 < old["nees_blocks"]["yaw"]


def test_a_straight_flight_keeps_its_heading_unknown(slow_flight: Path) -> None:
    """From 40 s the flight is straight to its end: nothing shows the heading, and the
    single arbitrary heading was 176° off at σ 1-2° (yaw NEES 81); the bank's estimate keeps
    the copies' spread as its yaw uncertainty (measured yaw NEES 3.2 of 1: each copy reads a
    little heading from the accelerometer's noise, and the weights drift with it), and the
    run says it ended without one (``init.heading_bank_std_deg``, measured 68°)."""
    from svains.replay import replay, resolve_config

    ds = load_dataset(slow_flight)
    config = RunConfig(method="ins", init=InitOptions(mode="gps"), use_mag=False,
                       replay=ReplayOptions(start_s=40.0))  # fmt: skip
    states: list = []
    replay(ds, resolve_config(ds, config), on_output=states.append)
    # streamed: the heading is not known, and its σ says so (a probe found it flagged known)
    assert states and not any(s.heading_known for s in states)
    rep = _ins(ds, 40.0, 8)
    assert "heading_found_s" not in rep["init"] and rep["init"]["heading_bank_std_deg"] > 30.0
    assert rep["nees_blocks"]["yaw"] < 5.0 and rep["nees_mean"] < 15.0  # measured 3.2, 12.3
    old = _ins(ds, 40.0, None)
    assert old["nees_blocks"]["yaw"] > 20.0 and old["nees_mean"] > 50.0  # measured 81, 98
