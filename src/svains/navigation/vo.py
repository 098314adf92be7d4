"""Method ``vo``: stereo visual odometry alone, chaining frame-to-frame egomotion (paper fig. 7).

No filter and no IMU: camera poses ``T_W_Ck = T_W_Ckm1 T_Ck_Ckm1^-1`` (``frontend.vo_chain``)
starting from the ground-truth pose at the first frame (identity without ground truth), mapped to
the body with ``T_C_B``. Frames without a motion estimate repeat the previous motion (constant
velocity) and are recorded as *tracking breaks* (``report["vo"]["break_t_ns"]``, fig. 7).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.frontend.types import Egomotion
from svains.frontend.vo_chain import chain_egomotion
from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat
from svains.models.state import PAPER
from svains.navigation.options import RunOptions
from svains.navigation.report import interpolate_groundtruth
from svains.navigation.runner import RunResult
from svains.navigation.tracks import TrackOptions
from svains.navigation.vision import VisionOptions
from svains.navigation.vision_sources import make_source
from svains.navigation.writers import write_outputs

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


def run(
    dataset: Dataset,
    options: RunOptions | None = None,
    progress: Callable[[float], None] | None = None,
    out_dir: Path | None = None,
) -> RunResult:
    """Chain the egomotion of every stereo frame; report like ``run_method`` (no covariance)."""
    options = options or RunOptions()
    vopts = VisionOptions.from_mapping(options.method_options)
    wall0 = time.perf_counter()
    source = make_source(
        dataset, vopts.source, TrackOptions(max_row_diff_px=vopts.max_row_diff_px, egomotion=True),
        vopts.frame_stride,
    )
    rig = source.rig
    times = source.frame_times()
    if options.duration_s is not None and times.size:
        times = times[times <= times[0] + int(options.duration_s * 1e9)]
    egos: list[Egomotion | None] = []
    t_list: list[int] = []
    for i, t in enumerate(times):
        tr = source.tracks_at(int(t))
        if tr is None:
            continue
        if not t_list:
            t_list.append(int(tr.t_prev_ns))
        egos.append(tr.egomotion)
        t_list.append(int(t))
        if progress is not None and i % 20 == 0:
            progress(i / max(1, len(times)))
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
    report: dict[str, Any] = {
        "method": "vo",
        "model": None,
        "dataset": dataset.name,
        "wall_s": wall,
        "data_duration_s": duration,
        "realtime_factor": duration / wall if wall > 0 else None,
        "vo": {"frames": n, "breaks": len(breaks), "break_t_ns": breaks, "source": source.kind},
    }
    result.report = report
    if out_dir is not None:
        write_outputs(Path(out_dir), result, PAPER)
    return result
