"""Evaluate trajectory files: TUM estimates against TUM or data-set ground truth."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.loader import load_dataset
from svains.datasets.trajectory import read_tum
from svains.datasets.types import GroundTruth
from svains.errors import DatasetError
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


def load_trajectory(path: Path | str) -> Trajectory:
    """A TUM file, or a data-set folder's ground truth (ASL or KITTI), as (t_ns, p, q_wxyz)."""
    p = Path(path)
    if p.is_dir():
        ds = load_dataset(p)
        if ds.groundtruth is None:
            raise DatasetError(f"{p}: data set has no ground truth")
        return groundtruth_trajectory(ds.groundtruth)
    return read_tum(p)


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
) -> EvaluationReport:
    """ATE (with ``align``) and RPE (per ``delta_m``) of a TUM estimate against a reference that
    is a TUM file or a data-set folder with ground truth."""
    t_e, p_e, q_e = load_trajectory(est_path)
    t_r, p_r, q_r = load_trajectory(ref_path)
    a = ate(t_e, p_e, q_e, t_r, p_r, q_r, align=align, max_diff_s=max_diff_s)
    r = rpe(t_e, p_e, q_e, t_r, p_r, q_r, delta_m=delta_m, max_diff_s=max_diff_s)
    return EvaluationReport(str(est_path), str(ref_path), a, r)
