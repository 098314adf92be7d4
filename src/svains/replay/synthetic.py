"""Simulated stereo features along a data set's real ground truth (issue 6, item 5).

For a real IMU recording with ground truth (EuRoC V1_01) but no usable images, landmarks are
scattered on the walls, floor and ceiling of a box ("room") around the flown path and projected
into the *rectified* stereo pair that the data set's cam0/cam1 calibrations define, with pixel
noise: a ``features0`` stream the vision methods consume like any other. The room is convex and
seen from inside, so no landmark hides another.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset, FeatureStream, GroundTruth
from svains.errors import DatasetError
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import quat_to_rotmat
from svains.replay.groundtruth import interpolate_groundtruth

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def room_landmarks(
    p_W_B: F64, n: int, rng: np.random.Generator, margin_m: tuple[float, float, float] = (3, 3, 1)
) -> F64:
    """``n`` points (n, 3) m uniformly on the six faces of the path's bounding box grown by
    ``margin_m`` (x, y, z), face chosen in proportion to its area."""
    lo = p_W_B.min(axis=0) - np.asarray(margin_m)
    hi = p_W_B.max(axis=0) + np.asarray(margin_m)
    size = hi - lo
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]]).repeat(2)
    face = rng.choice(6, size=n, p=areas / areas.sum())
    pts = lo + rng.random((n, 3)) * size
    axis = face // 2
    pts[np.arange(n), axis] = np.where(face % 2 == 0, lo[axis], hi[axis])
    return pts


def synthesize_features(
    frame_t_ns: I64,
    gt: GroundTruth,
    rig: RectifiedStereo,
    landmarks_W: F64,
    pixel_noise_std: float,
    rng: np.random.Generator,
    max_depth_m: float = 20.0,
) -> FeatureStream:
    """Noisy rectified left/right pixels of every landmark visible in both images at each frame.

    Track id = landmark index; rows sorted by time. Frames outside the ground truth are skipped.
    """
    inside, p_W_B, _, q_W_B = interpolate_groundtruth(gt, np.asarray(frame_t_ns, np.int64))
    times = np.asarray(frame_t_ns, np.int64)[inside]
    R_W_B = quat_to_rotmat(q_W_B)
    rows_t, rows_id, rows_l, rows_r = [], [], [], []
    for t, R, p in zip(times, R_W_B, p_W_B, strict=True):
        R_W_C = R @ rig.R_B_C
        p_W_C = p + R @ rig.p_B_C
        p_C = (landmarks_W - p_W_C) @ R_W_C  # R_C_W (p_W - p_W_C), (L, 3)
        vis = (p_C[:, 2] > 0.3) & (p_C[:, 2] < max_depth_m)
        ids = np.flatnonzero(vis)
        uvl = rig.project(p_C[ids]) + pixel_noise_std * rng.standard_normal((ids.size, 2))
        uvr = rig.project_right(p_C[ids]) + pixel_noise_std * rng.standard_normal((ids.size, 2))
        keep = rig.in_image(uvl, 1.0) & rig.in_image(uvr, 1.0) & (uvl[:, 0] > uvr[:, 0])
        rows_t.append(np.full(int(keep.sum()), t, np.int64))
        rows_id.append(ids[keep].astype(np.int64))
        rows_l.append(uvl[keep])
        rows_r.append(uvr[keep])
    if not rows_t:
        raise DatasetError("no stereo frame falls inside the ground truth")
    return FeatureStream(
        t_ns=np.concatenate(rows_t), track_id=np.concatenate(rows_id),
        uv_left=np.concatenate(rows_l), uv_right=np.concatenate(rows_r),
        pixel_noise_std=float(pixel_noise_std),
    )


def with_synthetic_features(
    ds: Dataset,
    rate_hz: float = 5.0,
    n_landmarks: int = 4000,
    pixel_noise_std: float = 0.5,
    seed: int = 0,
) -> Dataset:
    """Copy of ``ds`` whose ``features`` are simulated along its ground truth at ``rate_hz``."""
    if ds.groundtruth is None or len(ds.groundtruth.t_ns) < 2:
        raise DatasetError(f"{ds.root}: simulated features need ground truth")
    from svains.navigation.vision_sources import rig_from_calibrations

    rig = rig_from_calibrations(ds.cam0, ds.cam1)
    rng = np.random.default_rng(seed)
    gt = ds.groundtruth
    landmarks = room_landmarks(gt.p_W_B, n_landmarks, rng)
    step = round(1e9 / rate_hz)
    frames = np.arange(int(gt.t_ns[0]), int(gt.t_ns[-1]) + 1, step, dtype=np.int64)
    fs = synthesize_features(frames, gt, rig, landmarks, pixel_noise_std, rng)
    out = replace(ds, features=fs, extras={**ds.extras, "synthetic_landmarks_W": landmarks})
    return out
