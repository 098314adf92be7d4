"""features0 stream -> StereoTracks between consecutive frames."""

from __future__ import annotations

import numpy as np
import pytest

from _vision_truth import make_rig, two_frames
from svains.datasets.types import FeatureStream
from svains.errors import DatasetError
from svains.geometry.rotation import quat_to_rotmat
from svains.models.vision_lc import egomotion_from_state_pair
from svains.navigation.tracks import TrackOptions, tracks_from_features

RIG = make_rig()


def _stream(dt_s: float = 0.2, n: int = 40) -> tuple[FeatureStream, object]:
    tf = two_frames(RIG, dt_s, np.array([0.1, -0.2, 0.3]), np.array([0.2, 0.0, -0.1]), n)
    ids0 = np.arange(n, dtype=np.int64)
    # Frame k: drop track 0, add a new track 100, shuffle the row order.
    keep = np.arange(1, n)
    ids1 = np.append(ids0[keep], 100)[::-1]
    uvl1 = np.vstack([tf.uv_left[keep], [[10.0, 10.0]]])[::-1]
    uvr1 = np.vstack([tf.uv_right[keep], [[5.0, 10.0]]])[::-1]
    t0, t1 = 1_000_000_000, 1_000_000_000 + int(dt_s * 1e9)
    fs = FeatureStream(
        t_ns=np.array([t0] * n + [t1] * n, dtype=np.int64),
        track_id=np.concatenate([ids0, ids1]),
        uv_left=np.vstack([tf.uv_left_prev, uvl1]),
        uv_right=np.vstack([tf.uv_right_prev, uvr1]),
        pixel_noise_std=0.0,
    )
    return fs, tf


def test_tracks_match_ids_and_triangulate() -> None:
    fs, tf = _stream()
    (tr,) = tracks_from_features(fs, RIG)
    np.testing.assert_array_equal(tr.track_id, np.arange(1, 40))
    np.testing.assert_allclose(tr.p_Ckm1_F, tf.p_Ckm1_F[1:], rtol=1e-10)
    np.testing.assert_allclose(tr.uv_left, tf.uv_left[1:], atol=0)
    np.testing.assert_allclose(tr.uv_right_prev, tf.uv_right_prev[1:], atol=0)
    assert tr.inlier.all() and tr.egomotion is None
    assert (tr.t_prev_ns, tr.t_ns) == (1_000_000_000, 1_200_000_000)


def test_epipolar_and_disparity_gates_drop_features() -> None:
    fs, _ = _stream()
    uvr = fs.uv_right.copy()
    uvr[41, 1] += 5.0  # track 39's right pixel at frame k (rows reversed): epipolar fails
    uvr[3, 0] = fs.uv_left[3, 0] + 1.0  # track 3: negative disparity at k-1
    fs = FeatureStream(fs.t_ns, fs.track_id, fs.uv_left, uvr, 0.0)
    (tr,) = tracks_from_features(fs, RIG)
    bad = set(tr.track_id[~tr.inlier].tolist())
    assert bad == {3, 39}
    (tr,) = tracks_from_features(fs, RIG, TrackOptions(max_row_diff_px=None))
    assert set(tr.track_id[~tr.inlier].tolist()) == {3}


def test_egomotion_option_recovers_true_motion() -> None:
    fs, tf = _stream()
    (tr,) = tracks_from_features(fs, RIG, TrackOptions(egomotion=True))
    R_true, p_true = egomotion_from_state_pair(
        tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]), tf.x_k[0:3], RIG
    )
    assert tr.egomotion is not None and tr.inlier.all()
    np.testing.assert_allclose(tr.egomotion.R_Ck_Ckm1, R_true, atol=1e-6)
    np.testing.assert_allclose(tr.egomotion.p_Ck_Ckm1, p_true, atol=1e-6)


def test_unsorted_stream_is_rejected() -> None:
    fs, _ = _stream()
    bad = FeatureStream(fs.t_ns[::-1].copy(), fs.track_id, fs.uv_left, fs.uv_right, 0.0)
    with pytest.raises(DatasetError, match="not sorted"):
        tracks_from_features(bad, RIG)


def test_widen_option_links_frames_far_apart_for_lc_only() -> None:
    # Two frames seconds apart on a MAV-sized rig (40 deg turn, 1 m, points at 1.8-3.2 m,
    # 0.5 px noise): RANSAC at 1.5 px finds no motion; ``widen`` (lc's tracks) retries wider,
    # the default (vo's) leaves the frame without one.
    from svains.geometry.camera import RectifiedStereo
    from svains.geometry.rotation import so3_exp, so3_log

    rig = RectifiedStereo(458.0, 367.0, 248.0, 0.11, np.eye(3), np.zeros(3), 752, 480)
    R, t = so3_exp([0.0, np.radians(40.0), 0.0]), np.array([0.8, 0.1, -0.6])
    rng = np.random.default_rng(5)
    q = np.c_[rng.uniform(-1.2, 1.2, 300), rng.uniform(-0.8, 0.8, 300), rng.uniform(1.8, 3.2, 300)]
    p = (q - t) @ R  # the points in C_k-1 (q = R p + t)
    px = [rig.project(p), rig.project_right(p), rig.project(q), rig.project_right(q)]
    uvl0, uvr0, uvl1, uvr1 = (a + rng.normal(0, 0.5, a.shape) for a in px)
    uvr0[:, 1], uvr1[:, 1] = uvl0[:, 1], uvl1[:, 1]
    seen = (p[:, 2] > 0.5) & (uvl0[:, 0] > 0) & (uvl0[:, 0] < 752) & (uvl1[:, 0] > 0)
    seen &= uvl1[:, 0] < 752
    n = int(seen.sum())
    ids = np.arange(n, dtype=np.int64)
    fs = FeatureStream(np.repeat(np.array([0, 5_000_000_000], np.int64), n), np.r_[ids, ids],
                       np.vstack([uvl0[seen], uvl1[seen]]), np.vstack([uvr0[seen], uvr1[seen]]),
                       0.5)  # fmt: skip
    (plain,) = tracks_from_features(fs, rig, TrackOptions(egomotion=True))
    assert plain.egomotion is None and not plain.inlier.any()
    (wide,) = tracks_from_features(fs, rig, TrackOptions(egomotion=True, widen=True))
    ego = wide.egomotion
    assert ego is not None and wide.inlier.sum() >= n / 2
    assert np.linalg.norm(ego.p_Ck_Ckm1 - t) < 0.02
    assert np.degrees(np.linalg.norm(so3_log(ego.R_Ck_Ckm1 @ R.T))) < 0.5
