"""Run the stereo front end over a data set's image pairs and compare egomotion to ground truth."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset, GroundTruth
from svains.frontend.pipeline import FrameStats, FrontendOptions, StereoFrontend
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.rotation import quat_to_rotmat, so3_exp, so3_log

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)


@dataclass
class FrameRecord:
    """One processed frame: stats, egomotion (or None) and, with ground truth, its errors."""

    index: int
    stats: FrameStats
    egomotion: Egomotion | None
    translation_m: float = float("nan")
    rotation_deg: float = float("nan")
    gt_translation_m: float = float("nan")
    translation_error_m: float = float("nan")
    rotation_error_deg: float = float("nan")


@dataclass
class FrontendRun:
    """All frame records of a run; ``T_W_C_gt`` (F, 4, 4) rectified-left-camera truth or None."""

    records: list[FrameRecord] = field(default_factory=list)
    T_W_C_gt: F64 | None = None


def groundtruth_camera_poses(
    gt: GroundTruth, t_ns: NDArray[np.int64], R_B_C: F64, p_B_C: F64
) -> F64:
    """Camera poses ``T_W_C`` (F, 4, 4) at ``t_ns`` from body ground truth: position interpolated
    linearly, attitude along the geodesic, then ``T_W_C = T_W_B T_B_C``. Times outside the ground
    truth span are clamped to its ends."""
    tg = np.asarray(gt.t_ns, np.int64)
    t = np.clip(np.asarray(t_ns, np.int64), tg[0], tg[-1])
    j = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, max(tg.size - 2, 0))
    j1 = np.minimum(j + 1, tg.size - 1)
    span = np.maximum(tg[j1] - tg[j], 1)
    a = ((t - tg[j]) / span).astype(float)
    p = gt.p_W_B[j] + a[:, None] * (gt.p_W_B[j1] - gt.p_W_B[j])
    R0 = quat_to_rotmat(gt.q_W_B_wxyz[j])
    R1 = quat_to_rotmat(gt.q_W_B_wxyz[j1])
    R = R0 @ so3_exp(a[:, None] * so3_log(np.swapaxes(R0, 1, 2) @ R1))
    T = np.tile(np.eye(4), (t.size, 1, 1))
    T[:, :3, :3] = R @ R_B_C
    T[:, :3, 3] = p + R @ p_B_C
    return T


def run_frontend(
    ds: Dataset, pairs: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]],
    options: FrontendOptions | None = None,
    on_frame: Callable[[int, StereoTracks | None, StereoFrontend], None] | None = None,
) -> FrontendRun:
    """Process stereo ``pairs`` = (t_ns, left index, right index) of ``ds`` in order.

    ``on_frame(i, tracks, frontend)`` is called after each frame (e.g. to draw a figure).
    """
    if ds.cam0 is None or ds.cam1 is None or ds.left is None or ds.right is None:
        from svains.errors import DatasetError

        raise DatasetError(f"{ds.root}: the front end needs cam0 and cam1 images and calibration")
    fe = StereoFrontend.from_calibration(ds.cam0, ds.cam1, options)
    t_ns, il, ir = pairs
    run = FrontendRun()
    if ds.groundtruth is not None and len(ds.groundtruth.t_ns) > 0:
        run.T_W_C_gt = groundtruth_camera_poses(ds.groundtruth, t_ns, fe.rig.R_B_C, fe.rig.p_B_C)
    index_of = {int(t): i for i, t in enumerate(t_ns)}
    for i in range(t_ns.size):
        try:
            img_l = ds.left.load(int(il[i]))
            img_r = ds.right.load(int(ir[i]))
        except Exception as exc:  # an unreadable file is a dropped frame, not a crash
            log.warning("frame %d: cannot read images (%s)", i, exc)
            img_l = img_r = None
        tracks = fe.process(int(t_ns[i]), img_l, img_r)
        ego = tracks.egomotion if tracks is not None else None
        rec = FrameRecord(index=i, stats=fe.stats, egomotion=ego)
        if ego is not None:
            rec.translation_m = float(np.linalg.norm(ego.p_Ck_Ckm1))
            rec.rotation_deg = float(np.degrees(np.linalg.norm(so3_log(ego.R_Ck_Ckm1))))
        if run.T_W_C_gt is not None and tracks is not None:
            # Truth between the frame the tracks came from (the reference) and this one.
            T_rel = np.linalg.inv(run.T_W_C_gt[i]) @ run.T_W_C_gt[index_of[tracks.t_prev_ns]]
            rec.gt_translation_m = float(np.linalg.norm(T_rel[:3, 3]))
            if ego is not None:
                rec.translation_error_m = float(np.linalg.norm(ego.p_Ck_Ckm1 - T_rel[:3, 3]))
                dR = so3_log(T_rel[:3, :3].T @ ego.R_Ck_Ckm1)
                rec.rotation_error_deg = float(np.degrees(np.linalg.norm(dR)))
        run.records.append(rec)
        if on_frame is not None:
            on_frame(i, tracks, fe)
    return run


STAGES: tuple[str, ...] = (
    "rectify", "pyramid", "dense", "track", "stereo", "ransac", "detect", "total",
)  # fmt: skip


def frame_rows(run: FrontendRun) -> list[dict[str, object]]:
    """One flat row per frame (for ``frames.csv``): counts, egomotion, errors, stage timings."""
    rows: list[dict[str, object]] = []
    for r in run.records:
        ego = r.egomotion
        p = ego.p_Ck_Ckm1 if ego is not None else np.full(3, np.nan)
        w = so3_log(ego.R_Ck_Ckm1) if ego is not None else np.full(3, np.nan)
        row: dict[str, object] = {
            "index": r.index, "t_ns": r.stats.t_ns, "status": r.stats.status,
            "tracked": r.stats.tracked, "new": r.stats.new, "inliers": r.stats.inliers,
            "outliers": r.stats.outliers,
            "p_Ck_Ckm1_x": p[0], "p_Ck_Ckm1_y": p[1], "p_Ck_Ckm1_z": p[2],
            "theta_Ck_Ckm1_x": w[0], "theta_Ck_Ckm1_y": w[1], "theta_Ck_Ckm1_z": w[2],
            "translation_m": r.translation_m, "rotation_deg": r.rotation_deg,
            "gt_translation_m": r.gt_translation_m,
            "translation_error_m": r.translation_error_m,
            "rotation_error_deg": r.rotation_error_deg,
        }  # fmt: skip
        for s in STAGES:
            row[f"ms_{s}"] = r.stats.timings_ms.get(s, float("nan"))
        rows.append(row)
    return rows


def _med(x: list[float]) -> float | None:
    a = np.asarray(x, dtype=float)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def summarize(run: FrontendRun) -> dict[str, object]:
    """``report.json`` content: medians over frames with a motion measurement (the first frame
    has none); with ground truth also the errors and the chained-VO end-point drift."""
    from svains.frontend.vo_chain import chain_egomotion

    rec = run.records[1:] if run.records else []
    with_motion = [r for r in rec if r.egomotion is not None]
    out: dict[str, object] = {
        "frames": len(run.records),
        "frames_with_motion": len(with_motion),
        "inliers_median": _med([r.stats.inliers for r in rec]),
        "inliers_min": int(min((r.stats.inliers for r in rec), default=0)),
        "ms_per_frame": _med([r.stats.timings_ms.get("total", np.nan) for r in run.records]),
        "egomotion_translation_median_m": _med([r.translation_m for r in with_motion]),
        "egomotion_translation_max_m": max((r.translation_m for r in with_motion), default=None),
        "egomotion_rotation_median_deg": _med([r.rotation_deg for r in with_motion]),
        "egomotion_rotation_max_deg": max((r.rotation_deg for r in with_motion), default=None),
        "status_counts": {
            s: sum(r.stats.status == s for r in run.records)
            for s in sorted({r.stats.status for r in run.records})
        },
    }
    for s in STAGES:
        out[f"ms_{s}_median"] = _med([r.stats.timings_ms.get(s, np.nan) for r in run.records[1:]])
    if run.T_W_C_gt is not None:
        te = [r.translation_error_m for r in with_motion]
        step = [r.translation_error_m / r.gt_translation_m for r in with_motion
                if r.gt_translation_m > 0]
        out["egomotion_translation_error_median_m"] = _med(te)
        out["egomotion_translation_error_max_m"] = max(te, default=None)
        out["egomotion_translation_error_median_rel_step"] = _med(step)
        out["egomotion_rotation_error_median_deg"] = _med(
            [r.rotation_error_deg for r in with_motion]
        )
        out["egomotion_rotation_error_max_deg"] = max(
            (r.rotation_error_deg for r in with_motion), default=None
        )
        gt = run.T_W_C_gt
        T = chain_egomotion([r.egomotion for r in rec], gt[0])
        dist = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
        drift = float(np.linalg.norm(T[-1, :3, 3] - gt[-1, :3, 3]))
        out["vo_distance_m"] = dist
        out["vo_endpoint_drift_m"] = drift
        out["vo_endpoint_drift_rel_distance"] = drift / dist if dist > 0 else None
    return out
