"""Evaluate trajectories (TUM, EuRoC csv, KITTI, bag topic, data-set folder): ATE and RPE whose
figures equal evo's ``evo_ape`` / ``evo_rpe`` (checked in the tests, evo being test-only)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.trajectory_formats import TrajectoryFormat, read_trajectory
from svains.datasets.types import GroundTruth
from svains.evaluation.metrics import Alignment, AteResult, RpeResult, ate, rpe
from svains.outputs import atomic_write_text

Trajectory = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]


def groundtruth_trajectory(gt: GroundTruth) -> Trajectory:
    """(t_ns, p_W_B, q_W_B_wxyz) of a data set's ground truth."""
    return gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz


def ate_vs_groundtruth(
    t_est_ns: NDArray[np.int64],
    p_est: NDArray[np.float64],
    q_est_wxyz: NDArray[np.float64],
    gt: GroundTruth,
    align: Alignment = "se3",
    max_diff_s: float = 0.01,
) -> AteResult:
    """ATE of an estimate (body-in-world poses) against a data set's ground truth."""
    return ate(t_est_ns, p_est, q_est_wxyz, *groundtruth_trajectory(gt), align=align,
               max_diff_s=max_diff_s)  # fmt: skip


def load_trajectory(
    path: Path | str, fmt: TrajectoryFormat | None = None, topic: str | None = None
) -> Trajectory:
    """A trajectory file (TUM, EuRoC csv, KITTI poses), a bag's pose topic or a data-set
    folder's ground truth, as (t_ns, p, q_wxyz); ``fmt`` None auto-detects."""
    return read_trajectory(path, fmt, topic)


@dataclass
class EvaluationReport:
    """ATE and RPE of one estimate; ``to_json`` writes scalars only."""

    estimate: str
    reference: str
    ate: AteResult
    rpe: list[RpeResult]

    def to_dict(self) -> dict[str, object]:
        def clean(d: dict[str, object]) -> dict[str, object]:
            # JSON has no NaN: a segment length with no pairs is written as null.
            return {
                k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in d.items()
            }

        return {
            "estimate": self.estimate,
            "reference": self.reference,
            "ate": clean(self.ate.summary()),
            "rpe": [clean(asdict(r)) for r in self.rpe],
        }

    def to_json(self, path: Path | str) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")
        return path


def evaluate_files(
    est_path: Path | str,
    ref_path: Path | str,
    align: Alignment = "se3",
    delta_m: list[float] | tuple[float, ...] = (1.0, 5.0),
    max_diff_s: float = 0.01,
    est_format: TrajectoryFormat | None = None,
    ref_format: TrajectoryFormat | None = None,
    est_topic: str | None = None,
    ref_topic: str | None = None,
) -> EvaluationReport:
    """ATE (with ``align``) and RPE (per ``delta_m``) of an estimate against a reference, each
    in any format of :func:`load_trajectory` (auto-detected unless given)."""
    t_e, p_e, q_e = load_trajectory(est_path, est_format, est_topic)
    t_r, p_r, q_r = load_trajectory(ref_path, ref_format, ref_topic)
    a = ate(t_e, p_e, q_e, t_r, p_r, q_r, align=align, max_diff_s=max_diff_s)
    r = rpe(t_e, p_e, q_e, t_r, p_r, q_r, delta_m=delta_m, max_diff_s=max_diff_s,
            warn_ambiguous=False)  # said once, by the ATE's
    return EvaluationReport(str(est_path), str(ref_path), a, r)
