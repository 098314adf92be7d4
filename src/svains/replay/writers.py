"""Output files of a run: ``trajectory.tum``, ``trajectory_euroc.csv``, ``pose_covariance.csv``,
``states.csv``, ``updates.csv``, ``tracks.csv``, ``report.json`` (layouts in ``docs/formats.md``).

Each file is written atomically (temporary name, then rename), ``report.json`` last: a folder
with a ``report.json`` holds a complete run.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from svains.models.state import BIASED, PAPER, StateLayout
from svains.outputs import atomic_path, atomic_write_text

if TYPE_CHECKING:
    from svains.navigation.outputs import RunResult

# Every file ``write_outputs`` may write (a replaced run folder drops all of them).
RUN_FILES = ("trajectory.tum", "trajectory_euroc.csv", "pose_covariance.csv", "states.csv",
             "updates.csv", "tracks.csv", "config.yaml", "report.json",
             "trajectory_smoothed.tum", "trajectory_smoothed_euroc.csv",
             "pose_covariance_smoothed.csv", "states_smoothed.csv")  # fmt: skip

# EuRoC's state_groundtruth_estimate0/data.csv header (evo's euroc reader takes this layout).
EUROC_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
    "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
    "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
    "b_a_RS_S_z [m s^-2]"
)
_IU = np.triu_indices(3)
COVARIANCE_HEADER = "t_ns," + ",".join(
    [f"P_theta_{i}{j}" for i, j in zip(*_IU, strict=True)]
    + [f"P_p_{i}{j}" for i, j in zip(*_IU, strict=True)]
)

_STATE_NAMES = [
    "p_W_B_x", "p_W_B_y", "p_W_B_z", "v_W_B_x", "v_W_B_y", "v_W_B_z",
    "q_W_B_w", "q_W_B_x", "q_W_B_y", "q_W_B_z", "omega_B_x", "omega_B_y", "omega_B_z",
    "bg_B_x", "bg_B_y", "bg_B_z", "ba_B_x", "ba_B_y", "ba_B_z",
]  # fmt: skip
_STD_NAMES = [
    "std_p_x", "std_p_y", "std_p_z", "std_v_x", "std_v_y", "std_v_z",
    "std_theta_x", "std_theta_y", "std_theta_z", "std_omega_x", "std_omega_y", "std_omega_z",
    "std_bg_x", "std_bg_y", "std_bg_z", "std_ba_x", "std_ba_y", "std_ba_z",
]  # fmt: skip


def _json_default(o: object) -> object:
    return o.tolist() if hasattr(o, "tolist") else str(o)


def write_outputs(out_dir: Path, result: RunResult, layout: StateLayout | None = None,
                  config_text: str | None = None, report: bool = True) -> None:
    """Write the output files into ``out_dir`` (created if needed), ``config.yaml`` from
    ``config_text`` when given, ``report.json`` last (``report=False``: not at all, for a caller
    that writes more files and then ``write_report``); ``layout`` defaults to the one whose
    state size matches ``result.x``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if layout is None:
        layout = _layout_of(result)
    # A replaced run: its old report.json goes first, so old and new files never pass as one run.
    (out_dir / "report.json").unlink(missing_ok=True)
    write_tum(out_dir / "trajectory.tum", result)
    write_euroc_csv(out_dir / "trajectory_euroc.csv", result)
    if result.has_covariance and len(result.P9) == len(result.t_ns):  # (kept by the run)
        write_pose_covariance(out_dir / "pose_covariance.csv", result)
    write_states(out_dir / "states.csv", result, layout)
    # A replaced run's logs go when this run has none (the viewer would take them for its own).
    if result.update_log:
        write_updates(out_dir / "updates.csv", result)
    else:
        (out_dir / "updates.csv").unlink(missing_ok=True)
    if result.tracks is not None and len(result.tracks):
        write_tracks(out_dir / "tracks.csv", result)
    else:
        (out_dir / "tracks.csv").unlink(missing_ok=True)
    if config_text is not None:
        atomic_write_text(out_dir / "config.yaml", config_text)
    if report:
        write_report(out_dir, result.report)


def write_report(out_dir: Path, report: dict) -> None:
    """``report.json`` (the last file of a run: a folder with one holds a complete run)."""
    atomic_write_text(Path(out_dir) / "report.json",
                      json.dumps(report, indent=2, default=_json_default) + "\n")


def _layout_of(result: RunResult) -> StateLayout:
    """The state layout whose size matches ``result.x``."""
    return BIASED if result.x.shape[-1] == BIASED.nx else PAPER


def _csv_row(values: Sequence[float] | np.ndarray) -> str:
    """Comma-separated values, 9 significant digits, the first three (a position, m) 15: a
    georeferenced position (UTM northings reach 1e7 m) keeps its micrometres."""
    return ",".join([*(f"{v:.15g}" for v in values[:3]), *(f"{v:.9g}" for v in values[3:])])


def write_states(path: Path, result: RunResult, layout: StateLayout) -> None:
    """``states.csv``: t ns, the state (``layout.nx``) and its tangent standard deviations."""
    header = ",".join(["t_ns", *_STATE_NAMES[: layout.nx], *_STD_NAMES[: layout.ndx]])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(header + "\n")
        for t, xs, ss in zip(result.t_ns, result.x, result.std, strict=True):
            fh.write(f"{int(t)}," + _csv_row(np.concatenate([xs, ss])) + "\n")


def write_smoothed_outputs(out_dir: Path, smoothed: RunResult) -> None:
    """``trajectory_smoothed.tum``, ``trajectory_smoothed_euroc.csv``,
    ``pose_covariance_smoothed.csv`` and ``states_smoothed.csv`` of a smoothed run
    (``navigation.smoothing``: ω and the biases' deviations there are the forward ones), in the
    layouts of the forward files."""
    write_states(Path(out_dir) / "states_smoothed.csv", smoothed, _layout_of(smoothed))
    write_tum(Path(out_dir) / "trajectory_smoothed.tum", smoothed)
    write_euroc_csv(Path(out_dir) / "trajectory_smoothed_euroc.csv", smoothed)
    write_pose_covariance(Path(out_dir) / "pose_covariance_smoothed.csv", smoothed)


def write_tum(path: Path, result: RunResult) -> None:
    """TUM trajectory: ``t x y z qx qy qz qw`` (s, m, body-to-world quaternion)."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("# t x y z qx qy qz qw\n")
        for t, xs in zip(result.t_ns, result.x, strict=True):
            # Seconds written from the integer nanoseconds: no float64 rounding of the time.
            vals = " ".join(f"{v:.9f}" for v in (*xs[0:3], *xs[7:10], xs[6]))
            fh.write(f"{int(t) // 1_000_000_000}.{int(t) % 1_000_000_000:09d} {vals}\n")


def write_euroc_csv(path: Path, result: RunResult) -> None:
    """EuRoC ground-truth columns: t ns, p_W_B, q_W_B (w first), v_W_B, gyro and accelerometer
    biases (zeros when the model has none)."""
    x = result.x
    biases = x[:, 13:19] if x.shape[1] >= 19 else np.zeros((len(x), 6))
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(EUROC_HEADER + "\n")
        for t, xs, b in zip(result.t_ns, x, biases, strict=True):
            fh.write(f"{int(t)}," + _csv_row((*xs[0:3], *xs[6:10], *xs[3:6], *b)) + "\n")


def write_pose_covariance(path: Path, result: RunResult) -> None:
    """Per pose: t ns, the upper triangle (row-major: 00 01 02 11 12 22) of the attitude error's
    covariance (δθ, body frame, rad²), then of the position's (W frame, m²)."""
    P9 = result.P9
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(COVARIANCE_HEADER + "\n")
        for t, P in zip(result.t_ns, P9, strict=True):
            vals = (*P[6:9, 6:9][_IU], *P[0:3, 0:3][_IU])
            fh.write(f"{int(t)}," + ",".join(f"{v:.9g}" for v in vals) + "\n")


def write_updates(path: Path, result: RunResult) -> None:
    """One row per measurement update: ``t_ns,sensor,nis,dof,accepted`` (1 passed the gate)."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("t_ns,sensor,nis,dof,accepted\n")
        for u in result.update_log:
            s = u.stats
            fh.write(f"{u.t_ns},{u.sensor},{s.nis:.9g},{s.dof},{int(s.accepted)}\n")


def write_tracks(path: Path, result: RunResult) -> None:
    """One row per feature per frame: ``t_ns,track_id,u_px,v_px,inlier`` (left image pixel)."""
    assert result.tracks is not None
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("t_ns,track_id,u_px,v_px,inlier\n")
        for t, ids, uv, inl in result.tracks.frames:
            fh.writelines(f"{t},{i},{u:.3f},{v:.3f},{int(k)}\n"
                          for i, (u, v), k in zip(ids.tolist(), uv.tolist(), inl.tolist(),
                                                  strict=True))  # fmt: skip
