"""Taking back a leaning sensor's samples (``navigation.unfuse``): each block's share of a
joint update is the update with it minus the update without it, and un-fusing the shares of a
linear model's samples returns the filter exactly to where it was without them."""

from __future__ import annotations

import numpy as np
import pytest

from svains.filter import UKF, Euclidean, MerweScaledSigmaPoints
from svains.models.clones import CloneManifold, augment_clone
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, DP, DTH
from svains.navigation.unfuse import LeanShares, Share, unfuse

N = 4
P0 = np.diag([1.0, 2.0, 0.5, 1.5]) + 0.2


def _ukf() -> UKF:
    return UKF(Euclidean(N), MerweScaledSigmaPoints(N), np.zeros(N), P0.copy())


def _block(name: str, rows: list[int], z: list[float], r: float = 0.3) -> tuple:
    H = np.eye(N)[rows]
    return (lambda X: X @ H.T, np.array(z), np.full(len(rows), r), None, name)


A = _block("a", [0, 1], [0.4, -0.2])
M = _block("mag", [2, 3], [0.9, 0.1])


def test_a_blocks_share_is_the_joint_update_minus_the_update_without_it() -> None:
    joint, without, alone = _ukf(), _ukf(), _ukf()
    stats = joint.update_blocks([A, M], contribution_of="mag")
    without.update_blocks([A])
    alone.update_blocks([M], contribution_of="mag")
    share = next(s for s in stats if s.name == "mag").contribution
    assert share is not None and next(s for s in stats if s.name == "a").contribution is None
    np.testing.assert_allclose(share[0], joint.x - without.x, atol=1e-12)
    np.testing.assert_allclose(share[1], without.P - joint.P, atol=1e-12)
    # fused alone, its share is the whole update
    dx, dP = alone.update_blocks([M], contribution_of="mag")[0].contribution  # type: ignore[misc]
    assert np.abs(dx).max() > 0.1 and np.allclose(dP, dP.T)
    # a refused block has none
    far = _block("mag", [2, 3], [90.0, 0.1])
    assert _ukf().update_blocks([A, far], 0.99, contribution_of="mag")[1].contribution is None


def test_unfusing_a_linear_models_samples_restores_the_filter_without_them() -> None:
    fused, reference = _ukf(), _ukf()
    for u in (fused, reference):
        u.update_blocks([A])
    shares = LeanShares(("mag",), window=5)
    for k in range(3):  # three samples that lean the same way
        z = [0.9 + 0.1 * k, 0.1]
        for st in fused.update_blocks([_block("mag", [2, 3], z)], contribution_of="mag"):
            shares.observe(st, ())
    assert np.abs(fused.x - reference.x).max() > 0.3
    unfuse(fused, shares.take("mag"))
    np.testing.assert_allclose(fused.x, reference.x, atol=1e-12)
    np.testing.assert_allclose(fused.P, reference.P, atol=1e-12)
    assert shares.take("mag") == []  # taken once


def _with_clones() -> UKF:
    rng = np.random.default_rng(5)
    nav = NavManifold(BIASED)
    x = np.zeros(nav.nx)
    x[6] = 1.0  # q_W_B = identity
    A_ = rng.normal(size=(nav.ndx, nav.ndx))
    P_ = 0.01 * A_ @ A_.T + 0.01 * np.eye(nav.ndx)
    m = CloneManifold(nav, 0)
    x, P_, m = augment_clone(x, P_, m)
    x[0:3] += [2.0, -1.0, 0.5]
    x, P_, m = augment_clone(x, P_, m)
    return UKF(m, MerweScaledSigmaPoints(m.ndx), x, P_)


def test_a_clone_gets_back_its_own_share_or_that_of_the_latest_clone_before_it() -> None:
    ukf = _with_clones()
    m = ukf.manifold
    assert isinstance(m, CloneManifold) and m.n_clones == 2
    k = m.nav.ndx
    # a sample taken when the state held clone 10 only (as the first of the two now)
    dx = np.zeros(k + 6)
    dx[DP], dx[DTH] = [0.1, 0.2, 0.3], [0.01, 0.02, 0.03]
    dx[k:] = [0.04, 0.05, 0.06, 0.004, 0.005, 0.006]
    older = Share(dx, np.zeros((k + 6, k + 6)), (10,))
    # and one from before any clone
    bare = Share(dx[:k] * 2, np.eye(k), ())
    d = unfuse(ukf, [older, bare], clone_times=(10, 20))
    c0, c1 = m.tangent(0), m.tangent(1)
    np.testing.assert_allclose(d[:k], -3 * dx[:k])
    # clone 10: its own share, then the pose's of the bare sample (it copied that pose since)
    np.testing.assert_allclose(d[c0], -dx[k:] - 2 * np.r_[dx[DP], dx[DTH]])
    # clone 20, made after both: the latest clone's share of the first, the pose's of the other
    np.testing.assert_allclose(d[c1], -dx[k:] - 2 * np.r_[dx[DP], dx[DTH]])
    assert np.allclose(ukf.P, ukf.P.T)


def test_only_watched_accepted_updates_with_a_share_are_kept() -> None:
    shares = LeanShares(("mag",), window=2)
    ukf = _ukf()
    for st in ukf.update_blocks([A, M], contribution_of="mag"):
        shares.observe(st, (1,))
    for st in ukf.update_blocks([M]):  # no share asked for
        shares.observe(st, (1,))
    taken = shares.take("mag")
    assert len(taken) == 1 and taken[0].clone_times == (1,)
    assert shares.take("gps") == []


@pytest.mark.parametrize("n", [6, 9])
def test_the_window_keeps_the_last_samples(n: int) -> None:
    shares = LeanShares(("mag",), window=5)
    ukf = _ukf()
    for _ in range(n):
        for st in ukf.update_blocks([M], contribution_of="mag"):
            shares.observe(st, ())
    assert len(shares.take("mag")) == 5


def test_a_smoother_crosses_the_updates_taken_back() -> None:
    """Un-fusing is an instant's change, as an update is: the smoother's chain is not cut, and
    on a linear model every smoothed epoch, the ones that had the samples in them too, equals
    that of a run that never fused them (it was a cut: a false lean alarm on a clean flight
    stepped the smoothed trajectory by 15 cm: a user's probe)."""
    from svains.filter.rts import RtsRecorder, smooth

    runs = []
    for with_mag in (True, False):
        u = _ukf()
        rec = RtsRecorder()
        u.recorder = rec
        rec.start(u.x, u.P)
        u.update_blocks([A])
        rec.mark(1, u.x, u.P)
        shares = LeanShares(("mag",), window=5)
        if with_mag:
            for k in range(3):
                z = [0.9 + 0.1 * k, 0.1]
                for st in u.update_blocks([_block("mag", [2, 3], z)], contribution_of="mag"):
                    shares.observe(st, ())
        rec.mark(2, u.x, u.P)  # the samples are in this epoch's forward estimate
        if with_mag:
            unfuse(u, shares.take("mag"))
        u.update_blocks([_block("b", [0, 2], [0.1, 0.3])])
        rec.mark(3, u.x, u.P, last=True)
        runs.append((rec, smooth(rec), u))
    (rec, s, u), (_, s_ref, u_ref) = runs
    assert rec.cuts == 0
    np.testing.assert_allclose(u.x, u_ref.x, atol=1e-12)
    x_s = s.x + s.eps  # Euclidean: the smoothed means
    np.testing.assert_allclose(x_s, s_ref.x + s_ref.eps, atol=1e-10)
    np.testing.assert_allclose(s.P, s_ref.P, atol=1e-10)
    assert np.abs(s.x[1] - s_ref.x[1]).max() > 0.3  # the forward epoch 2 had the samples
