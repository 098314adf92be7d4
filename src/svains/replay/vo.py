"""Method ``vo``: stereo visual odometry alone, chaining frame-to-frame egomotion (paper fig. 7).

No filter and no IMU: camera poses ``T_W_Ck = T_W_Ckm1 T_Ck_Ckm1^-1`` (``frontend.vo_chain``)
starting from the ground-truth pose at the first frame (identity without ground truth), mapped to
the body with ``T_C_B``. Frames without a motion estimate repeat the previous motion (constant
velocity) and are recorded as *tracking breaks* (``report["vo"]["break_t_ns"]``, fig. 7).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.loader import PairReader, stereo_pairs
from svains.datasets.types import Dataset
from svains.errors import DatasetError
from svains.frontend.types import Egomotion, StereoTracks
from svains.frontend.vo_chain import chain_egomotion
from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat
from svains.models.state import PAPER
from svains.navigation.options import RunConfig
from svains.navigation.outputs import RunResult
from svains.navigation.tracks import TrackOptions, frame_slices
from svains.navigation.vision_sources import FeatureFrames, ImageFrames, rig_from_calibrations
from svains.replay.groundtruth import interpolate_groundtruth

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

log = logging.getLogger(__name__)


def _start_pose(ds: Dataset, t0_ns: int, R_B_C: F64, p_B_C: F64) -> tuple[F64, bool]:
    """``T_W_C`` (4, 4) at the first frame from ground truth (identity camera pose without), and
    whether it came from the ground truth."""
    T_W_C = np.eye(4)
    if ds.groundtruth is None:
        return T_W_C, False
    inside, p, _, q = interpolate_groundtruth(ds.groundtruth, np.array([t0_ns], np.int64))
    if not inside[0]:
        return T_W_C, False
    R_W_B = quat_to_rotmat(q[0])
    T_W_C[:3, :3] = R_W_B @ R_B_C
    T_W_C[:3, 3] = p[0] + R_W_B @ p_B_C
    return T_W_C, True


def body_states_from_camera_poses(t_ns: I64, T_W_C: F64, R_B_C: F64, p_B_C: F64) -> F64:
    """13-number states (K, 13) (p, v by finite differences, q, ω = 0) of the body."""
    R_W_B = T_W_C[:, :3, :3] @ R_B_C.T
    p_W_B = T_W_C[:, :3, 3] - np.einsum("kij,j->ki", R_W_B, p_B_C)
    x = np.zeros((len(t_ns), 13))
    x[:, 0:3] = p_W_B
    if len(t_ns) >= 2:
        x[:, 3:6] = np.gradient(p_W_B, t_ns * 1e-9, axis=0)
    x[:, 6:10] = rotmat_to_quat(R_W_B)
    return x


def _frame_tracks(
    ds: Dataset, config: RunConfig, t0_ns: int
) -> Iterator[tuple[int, StereoTracks | None]]:
    """(t_ns, tracks) of every frame from ``t0_ns`` on that may carry tracks, after
    ``frame_stride`` and ``duration_s`` (counted from the first such frame)."""
    v = config.vision
    stride = max(1, v.frame_stride)
    opts = TrackOptions(max_row_diff_px=v.max_row_diff_px, egomotion=True,
                        bundle=v.bundle_for("vo"))
    end: int | None = None
    if v.source == "features" and ds.features is not None:
        feats = FeatureFrames(rig_from_calibrations(ds.cam0, ds.cam1), opts)
        times, bounds = frame_slices(ds.features)
        fs = ds.features
        k0 = int(np.searchsorted(times, t0_ns))
        for k in range(k0, len(times), stride):
            t = int(times[k])
            rows = slice(bounds[k], bounds[k + 1])
            if not feats.push(t, fs.track_id[rows], fs.uv_left[rows], fs.uv_right[rows]):
                continue
            if end is None and config.duration_s is not None:
                end = t + int(config.duration_s * 1e9)
            if end is not None and t > end:
                return
            yield t, feats.tracks_at(t)
        return
    if ds.left is None or ds.right is None:
        raise DatasetError(f"{ds.root}: vo needs features0 or cam0/cam1 images")
    images = ImageFrames(ds.cam0, ds.cam1, bundle=v.bundle_for("vo"))
    reader = PairReader(ds)
    t_all, il, ir = stereo_pairs(ds)
    for k in range(int(np.searchsorted(t_all, t0_ns)), len(t_all), stride):
        t = int(t_all[k])
        if end is None and config.duration_s is not None:
            end = t + int(config.duration_s * 1e9)
        if end is not None and t > end:
            return
        pair = reader.read(int(il[k]), int(ir[k]), t)
        if pair is None:  # unreadable: dropped (``PairReader`` warned)
            continue
        images.push(t, *pair)
        yield t, images.tracks_at(t)


def _first_ns(ds: Dataset) -> int:
    """The recording's origin: its first IMU sample, else its first stereo frame."""
    if ds.imu is not None and len(ds.imu.t_ns):
        return int(ds.imu.t_ns[0])
    if ds.features is not None and len(ds.features.t_ns):
        return int(np.min(ds.features.t_ns))
    if ds.left is not None and len(ds.left.t_ns):
        return int(np.min(ds.left.t_ns))
    raise DatasetError(f"{ds.root}: vo needs features0 or cam0/cam1 images")


def run(
    dataset: Dataset,
    config: RunConfig,
    progress: Callable[[float], None] | None = None,
) -> RunResult:
    """Chain the egomotion of every stereo frame; report like ``run_method`` (no covariance)."""
    wall0 = time.perf_counter()
    rig = rig_from_calibrations(dataset.cam0, dataset.cam1)
    egos: list[Egomotion | None] = []
    t_list: list[int] = []
    kind = config.vision.source
    # ``--start``: the same origin as the filter methods' replay (the first IMU sample); a
    # stereo-only data set (KITTI odometry) counts from its first frame.
    t0 = _first_ns(dataset) + int(config.replay.start_s * 1e9)
    for i, (_, tr) in enumerate(_frame_tracks(dataset, config, t0)):
        if tr is None:
            continue
        if not t_list:
            t_list.append(int(tr.t_prev_ns))
        egos.append(tr.egomotion)
        t_list.append(int(tr.t_ns))
        if progress is not None and i % 20 == 0:
            progress(0.5)
    t_ns = np.array(t_list, dtype=np.int64)
    breaks = [int(t) for t, e in zip(t_ns[1:], egos, strict=True) if e is None]
    R_B_C, p_B_C = np.asarray(rig.R_B_C, float), np.asarray(rig.p_B_C, float)
    T0, from_gt = (
        _start_pose(dataset, int(t_ns[0]), R_B_C, p_B_C) if t_ns.size else (np.eye(4), False)
    )
    T_W_C = chain_egomotion(egos, T0)
    x = body_states_from_camera_poses(t_ns, T_W_C, R_B_C, p_B_C)
    wall = time.perf_counter() - wall0
    if progress is not None:
        progress(1.0)
    n = len(t_ns)
    # VO carries no covariance: identity keeps the shared report code working, NEES is dropped.
    P9 = np.broadcast_to(np.eye(9), (n, 9, 9)).copy()
    result = RunResult(
        t_ns, x, np.full((n, PAPER.ndx), np.nan), P9, {},
        world_frame="groundtruth" if from_gt else "local", has_covariance=False,
    )  # fmt: skip
    duration = (t_ns[-1] - t_ns[0]) * 1e-9 if n >= 2 else 0.0
    if breaks and n >= 2:
        # The trajectory goes on at the last motion across each: the drift after it is not the
        # odometry's (a user's probe: KITTI raw at every 10th pair, 3 breaks, 74 % of the path).
        first = (breaks[0] - int(t_ns[0])) * 1e-9
        log.warning("vo: tracking broke at %d of %d frames (first %.2f s in): each bridged at "
                    "the last motion, so the trajectory after it carries that guess; frames "
                    "too far apart, too few features or a fast turn?", len(breaks), n - 1,
                    first)  # fmt: skip
    report: dict[str, Any] = {
        "method": "vo",
        "model": None,
        "dataset": dataset.name,
        "wall_s": wall,
        "data_duration_s": duration,
        "realtime_factor": duration / wall if wall > 0 else None,
        "vo": {"frames": n, "breaks": len(breaks), "break_t_ns": breaks, "source": kind},
    }
    result.report = report
    return result
