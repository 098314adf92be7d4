"""Relocalisation against stored keyframes (``navigation.relocalise``): the covariance rule
that keeps a keyframe taken as independent consistent, the keyframe memory, and the clone it
puts in the filter's state."""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF
from svains.models.clones import CloneManifold, augment_independent_clone
from svains.models.manifold import NavManifold
from svains.models.state import BIASED
from svains.navigation.options import VisionOptions
from svains.navigation.relocalise import (
    WEAK_INFLATION,
    Keyframe,
    KeyframeMemory,
    by_view,
    keyframe_covariance,
    most_shared,
)
from svains.navigation.tracks import TrackOptions, pair_frames
from svains.navigation.vision_clones import CloneWindow

S = 1_000_000_000


def _fused_error_variances(r: float, c: float, n: int = 400_000) -> tuple[float, float]:
    """Monte Carlo of one scalar relocalisation: keyframe error ``e_j`` (variance 1), the
    state's error ``e_k = e_j + drift`` (variance ``r``), an exact measurement of ``x_k - x_j``
    fused with the keyframe taken as independent at variance ``c``: (true variance of the
    fused error, the variance the update reports)."""
    rng = np.random.default_rng(7)
    e_j = rng.standard_normal(n)
    e_k = e_j + np.sqrt(r - 1.0) * rng.standard_normal(n)
    K = r / (r + c)
    fused = e_k - K * (e_k - e_j)
    return float(np.var(fused)), r * (1.0 - K)


def test_the_inflation_rule_keeps_the_fused_pose_consistent() -> None:
    P_kf = np.diag([0.04, 0.04, 0.04, 1e-4, 1e-4, 1e-4])
    for r in (2.5, 3.0, 4.0, 10.0):
        P = keyframe_covariance(P_kf, r * P_kf, min_ratio=2.5, min_inflation=1.0)
        assert P is not None
        c = P[0, 0] / P_kf[0, 0]
        assert c == pytest.approx(r / (r - 2.0))
        true, reported = _fused_error_variances(r, c)
        assert true <= reported * 1.01  # consistent (the rule is exact: equal)
        assert true == pytest.approx(reported, rel=0.02)
        # Without the inflation the same update is overconfident.
        true1, reported1 = _fused_error_variances(r, 1.0)
        assert true1 > 1.1 * reported1


def test_a_block_that_has_not_drifted_is_fused_wide_and_stays_near_consistent() -> None:
    P_kf = np.diag([0.04, 0.04, 0.04, 1e-4, 1e-4, 1e-4])
    P_now = np.diag([0.4, 0.4, 0.4, 1.5e-4, 1.5e-4, 1.5e-4])  # attitude ratio 1.5
    P = keyframe_covariance(P_kf, P_now, min_ratio=2.5, min_inflation=1.5)
    assert P is not None
    assert P[0, 0] == pytest.approx(0.04 * 1.5)  # r = 10: r / (r - 2) = 1.25 < the floor
    assert P[3, 3] == pytest.approx(1e-4 * WEAK_INFLATION)
    for r in (1.0, 1.5, 2.0, 2.4):  # the weak factor's update is within 4 % of consistent
        true, reported = _fused_error_variances(r, WEAK_INFLATION)
        assert true <= 1.04 * reported
    # Position that has not drifted: no relocalisation at all.
    assert keyframe_covariance(P_kf, 2.0 * P_kf, 2.5, 1.5) is None


def _frame(t_s: float, ids: list[int]) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    n = len(ids)
    u = np.linspace(100.0, 600.0, n)
    uvl = np.column_stack([u, np.full(n, 240.0)])
    return (round(t_s * S), np.asarray(ids, np.int64), uvl, uvl - [20.0, 0.0])


def _nav_state(pos_var: float) -> tuple[np.ndarray, np.ndarray]:
    x = np.zeros(BIASED.nx)
    x[6] = 1.0
    return x, np.eye(BIASED.ndx) * pos_var


def test_keyframes_are_spaced_and_thinned_when_full() -> None:
    mem = KeyframeMemory(spacing_s=1.0, max_keyframes=4)
    x, P = _nav_state(0.01)

    def remember(t_s: float) -> bool:
        f = _frame(t_s, [1, 2, 3])
        return mem.remember(f[0], f, x, P)

    assert remember(0.0)
    assert not mem.due(round(0.5 * S)) and not remember(0.5)  # within the spacing
    for t in (1.0, 2.0, 3.0, 4.0):
        remember(t)
    # Full at 5: every other one dropped, the spacing doubled.
    assert [k.t_ns // S for k in mem.keyframes] == [0, 2, 4]
    assert mem.spacing_ns == 2 * S
    assert not remember(5.0)
    assert remember(6.0)
    # 3 ids (8 bytes) and 2x3 pixels (8 bytes) each, the 6x6 covariance and the pose.
    assert mem.n_bytes == 4 * (3 * 8 + 2 * 3 * 2 * 8 + 36 * 8 + 7 * 8)


def _kf(t_s: float, ids: list[int], pos_var: float) -> Keyframe:
    x, P = _nav_state(pos_var)
    f = _frame(t_s, ids)
    return Keyframe(f[0], f, x[:3], x[6:10], P[:6, :6])


def test_the_best_keyframe_shares_most_and_is_the_most_certain_of_those() -> None:
    kfs = [_kf(0.0, list(range(0, 10)), 0.09),  # shares 10
           _kf(1.0, list(range(0, 6)), 0.01),  # shares 6 (>= half)
           _kf(2.0, list(range(0, 4)), 0.0001)]  # shares 4 (< half)  # fmt: skip
    found = most_shared(kfs, _frame(5.0, list(range(0, 12))), min_shared=3)
    assert found is not None
    kf, n = found
    assert kf.t_ns == 1 * S and n == 6
    assert kf.position_variance == pytest.approx(0.03)
    assert most_shared(kfs, _frame(5.0, [50, 51, 52]), min_shared=3) is None  # shares nothing
    assert most_shared(kfs, _frame(5.0, [0, 1]), min_shared=3) is None  # too few


def test_keyframes_by_view_keep_the_cameras_that_looked_the_same_way_nearby() -> None:
    R_B_C, p_B_C = np.eye(3), np.zeros(3)  # camera axes = body axes: looks along body z

    def kf(p: list[float], yaw_deg: float) -> Keyframe:
        h = np.radians(yaw_deg) / 2  # a turn about x tilts the optical axis (z) by the angle
        return Keyframe(0, None, np.asarray(p, float), np.array([np.cos(h), np.sin(h), 0, 0]),
                        np.eye(6))  # fmt: skip

    x, _ = _nav_state(0.01)  # at the origin, identity attitude
    near_turned, far, near_same, behind = (kf([0.5, 0, 0], 40.0), kf([9.0, 0, 0], 0.0),
                                           kf([1.0, 0, 0], 5.0), kf([0, 0, 0], 150.0))
    got = by_view([near_turned, far, near_same, behind], x, R_B_C, p_B_C, 60.0, 5.0)
    assert got == [near_same, near_turned]


def test_frames_far_apart_pair_on_their_shared_ids() -> None:
    from svains.geometry.camera import RectifiedStereo

    rig = RectifiedStereo(400.0, 320.0, 240.0, 0.1, np.eye(3), np.zeros(3), 640, 480)
    a, b = _frame(0.0, [5, 7, 9, 11]), _frame(30.0, [11, 3, 7])
    tr = pair_frames(a, b, rig, TrackOptions())
    assert tr.t_prev_ns == 0 and tr.t_ns == 30 * S
    assert tr.track_id.tolist() == [7, 11]
    np.testing.assert_allclose(tr.uv_left_prev[:, 0], a[2][[1, 3], 0])
    np.testing.assert_allclose(tr.uv_left[:, 0], b[2][[2, 0], 0])
    assert tr.inlier.all() and tr.egomotion is None
    np.testing.assert_allclose(tr.p_Ckm1_F[:, 2], 400.0 * 0.1 / 20.0)


def test_a_keyframe_enters_the_state_uncorrelated_and_leaves_it_as_it_was() -> None:
    manifold = CloneManifold(NavManifold(BIASED))
    rng = np.random.default_rng(3)
    A = rng.standard_normal((manifold.ndx, manifold.ndx))
    P0 = A @ A.T + np.eye(manifold.ndx)
    x0 = np.zeros(manifold.nx)
    x0[6] = 1.0
    ukf = UKF(manifold, MerweScaledSigmaPoints(manifold.ndx, 1e-3, 2.0, 0.0), x0, P0)
    window = CloneWindow()
    p_kf, q_kf = np.array([1.0, 2.0, 3.0]), np.array([2.0, 0.0, 0.0, 0.0])  # normalised
    P_kf = np.diag([0.1, 0.2, 0.3, 1e-3, 2e-3, 3e-3])
    window.add_keyframe(ukf, 5 * S, p_kf, q_kf, P_kf)
    cols = window.columns(ukf, 5 * S)
    assert cols is not None
    np.testing.assert_allclose(ukf.x[cols[0]], p_kf)
    np.testing.assert_allclose(ukf.x[cols[1]], [1.0, 0.0, 0.0, 0.0])
    n = manifold.ndx
    np.testing.assert_allclose(ukf.P[n:, :n], 0.0)
    np.testing.assert_allclose(np.diag(ukf.P)[n:], np.diag(P_kf) * (1 + 1e-9), rtol=1e-6)
    with pytest.raises(ValueError, match="already holds a clone"):
        window.add_keyframe(ukf, 5 * S, p_kf, q_kf, P_kf)
    window.drop(ukf, 5 * S)
    assert window.times == []
    np.testing.assert_array_equal(ukf.x, x0)
    np.testing.assert_allclose(ukf.P, P0)


def test_an_independent_clone_refuses_a_wrong_covariance() -> None:
    manifold = CloneManifold(NavManifold(BIASED))
    x = np.zeros(manifold.nx)
    x[6] = 1.0
    with pytest.raises(ConfigError, match=r"a pose covariance is \(6, 6\)"):
        augment_independent_clone(x, np.eye(manifold.ndx), manifold, np.zeros(3),
                                  np.array([1.0, 0, 0, 0]), np.eye(3))  # fmt: skip


@pytest.mark.parametrize(("field", "value", "fragment"), [
    ("relocalise_min_drift", 2.0, "relocalise_min_drift > 2"),
    ("relocalise_inflation", 0.5, "relocalise_inflation must be >= 1"),
    ("relocalise_min_features", 2, "relocalise_min_features must be >= 3"),
])  # fmt: skip
def test_bad_relocalisation_settings_are_refused(field: str, value: float, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        VisionOptions(**{field: value})


def test_recorded_features_relocalise_on_the_keyframe_that_shares_their_ids() -> None:
    from svains.geometry.camera import RectifiedStereo
    from svains.navigation.vision_sources import FeatureFrames

    rig = RectifiedStereo(400.0, 320.0, 240.0, 0.1, np.eye(3), np.zeros(3), 640, 480)
    source = FeatureFrames(rig, TrackOptions())
    kfs = []
    for t_s, ids in ((0.0, list(range(0, 30))), (1.0, list(range(100, 130)))):
        f = _frame(t_s, ids)
        source.push(*f)
        source.tracks_at(f[0])
        got = source.keyframe_features(f[0])
        assert got is not None and got[0] == f[0]
        kfs.append(_kf(t_s, ids, 0.01))
    # A frame that shares nothing with the one before and 25 ids with the first keyframe.
    cur = _frame(9.0, [*range(5, 30), 500, 501])
    source.push(*cur)
    tr = source.tracks_at(cur[0])
    assert tr is not None and tr.track_id.size == 0
    assert source.keyframe_features(round(8.0 * S)) is None  # not the frame asked for
    found = source.relocalisation_tracks(cur[0], kfs, min_features=20)
    assert found is not None
    kf, tr = found
    assert kf.t_ns == 0 and tr.t_prev_ns == 0 and tr.t_ns == 9 * S
    assert tr.track_id.tolist() == list(range(5, 30)) and tr.inlier.all()
    assert source.relocalisation_tracks(cur[0], kfs, min_features=26) is None
