"""Simulated features along a real ground truth (issue 6, item 5)."""

from __future__ import annotations

import numpy as np

from _vision_truth import make_rig
from svains.datasets.types import GroundTruth
from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat, so3_exp
from svains.navigation.tracks import tracks_from_features
from svains.replay.synthetic import room_landmarks, synthesize_features

RIG = make_rig()


def _gt() -> GroundTruth:
    t = np.linspace(0.0, 4.0, 81)
    p = np.column_stack([0.5 * t, 0.2 * np.sin(t), 1.0 + 0.0 * t])
    q = rotmat_to_quat(so3_exp(np.column_stack([0 * t, 0 * t, 0.1 * t])))
    z = np.zeros((len(t), 3))
    return GroundTruth((t * 1e9).astype(np.int64), p, q, np.gradient(p, t, axis=0), z, z)


def test_room_landmarks_lie_on_the_box_faces() -> None:
    p = np.array([[0.0, 0, 0], [2.0, 1, 1]])
    pts = room_landmarks(p, 500, np.random.default_rng(0), margin_m=(1, 1, 1))
    lo, hi = np.array([-1.0, -1, -1]), np.array([3.0, 2, 2])
    on_face = np.isclose(pts, lo).any(axis=1) | np.isclose(pts, hi).any(axis=1)
    assert on_face.all() and (pts >= lo - 1e-12).all() and (pts <= hi + 1e-12).all()


def test_noise_free_features_are_exact_projections_and_track() -> None:
    gt = _gt()
    rng = np.random.default_rng(1)
    lm = room_landmarks(gt.p_W_B, 2000, rng)
    frames = np.arange(0, 4_000_000_001, 200_000_000, dtype=np.int64)
    fs = synthesize_features(frames, gt, RIG, lm, 0.0, rng)
    assert len(fs.frame_times()) == 21 and len(fs.t_ns) > 21 * 30
    # Re-project one frame by hand.
    k = 10
    sel = fs.t_ns == frames[k]
    R = quat_to_rotmat(gt.q_W_B_wxyz[4 * k])  # ground truth every 0.05 s
    p_C = (lm[fs.track_id[sel]] - (gt.p_W_B[4 * k] + R @ RIG.p_B_C)) @ (R @ RIG.R_B_C)
    np.testing.assert_allclose(fs.uv_left[sel], RIG.project(p_C), atol=1e-9)
    np.testing.assert_allclose(fs.uv_right[sel], RIG.project_right(p_C), atol=1e-9)
    tracks = tracks_from_features(fs, RIG)
    assert len(tracks) == 20 and min(int(t.inlier.sum()) for t in tracks) > 20
