"""Run several navigation methods on one data set and tabulate them (``svains compare``).

Per method: the runner's ``report.json`` content plus
- ``ate_m`` with the alignment that fits the run (``ate_alignment``): ``none`` when GPS fixes the
  world frame, ``posyaw`` (yaw + translation: what a GPS-denied visual-inertial filter cannot
  observe) otherwise, also for VO started from the true pose; ``se3`` for VO in a local frame;
- ``ate_frames_m``: the same ATE over the poses at the recorded stereo frames only
  (``frame_rows``; None without ``features0``): ``vo`` writes a pose per frame, the filters
  between frames too, where only the IMU carries them, so this compares the methods at the
  same stamps;
- ``outage_max_error_m``: the largest position error inside each GPS outage (gaps in ``gps0``);
- ``final_position_error_m``, ``path_length_m`` and their ratio ``final_error_pct_of_path``
  (the final error is taken after the ATE's alignment when the run's world frame is local, i.e. a
  static start without GPS; raw otherwise).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset, GroundTruth
from svains.errors import AlignmentError, ConfigError
from svains.evaluation.extrinsics import write_estimated_camchain
from svains.evaluation.metrics import AteResult, ate, matching_time_indices
from svains.evaluation.run import add_smoothed, run_accuracy, run_owned
from svains.navigation.options import RunConfig
from svains.navigation.outputs import RunResult
from svains.outputs import TMP_PREFIX, atomic_write_text, replaced_dir
from svains.replay import replay, resolve_config
from svains.replay.groundtruth import interpolate_groundtruth
from svains.replay.writers import write_outputs, write_smoothed_outputs

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

log = logging.getLogger(__name__)

FRAME_MATCH_NS = 5_000_000  # ``frame_rows``: an output pose within 5 ms of a frame is its pose

METHODS: tuple[str, ...] = ("ins", "vo", "lc", "tc", "3d")


def gps_outages(ds: Dataset, min_gap_factor: float = 3.0) -> list[tuple[int, int]]:
    """GPS outages ``(t_start_ns, t_end_ns)``: gaps longer than ``min_gap_factor`` median periods
    (the last fix before and the first after)."""
    if ds.gps is None or len(ds.gps.t_ns) < 3:
        return []
    t = np.asarray(ds.gps.t_ns, np.int64)
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > min_gap_factor * np.median(dt))
    return [(int(t[i]), int(t[i + 1])) for i in gaps]


def _position_errors(t_ns: I64, p_W_B: F64, gt: GroundTruth) -> tuple[I64, F64]:
    inside, p_gt, _, _ = interpolate_groundtruth(gt, t_ns)
    return t_ns[inside], np.linalg.norm(p_W_B[inside] - p_gt, axis=1)


def outage_max_errors(
    t_ns: I64, p_W_B: F64, gt: GroundTruth, outages: Sequence[tuple[int, int]]
) -> list[float | None]:
    """Max position error (m, no alignment) of the estimate inside each outage, from the last
    fix before it up to, not including, the first fix after it: the state logged at that fix
    is already corrected by it, and its error is the fix's noise, not the outage's drift (the
    window of ``svains run``'s report, ``evaluation.accuracy.gps_outage_report``)."""
    t, err = _position_errors(t_ns, p_W_B, gt)
    out: list[float | None] = []
    for a, b in outages:
        sel = (t >= a) & (t < b)
        out.append(float(err[sel].max()) if sel.any() else None)
    return out


def ate_alignment(method: str, gps_used: bool, world_frame: str = "groundtruth") -> str:
    """The alignment that fits a run: ``none`` when GPS fixes the world frame, ``posyaw`` (the 4
    DoF a GPS-denied visual-inertial filter cannot observe) otherwise; ``se3`` for pure VO only
    when it started in a local frame. VO started from the true pose is aligned like the filters
    (``posyaw``): they had the same information at the start, and its roll and pitch drift is a
    real error that gravity spares the filters (aligning it away would favour VO)."""
    if method == "vo":
        return "posyaw" if world_frame == "groundtruth" else "se3"
    return "none" if gps_used else "posyaw"


def align_to_groundtruth(
    result: RunResult, ds: Dataset, align: str, rows: NDArray[np.int64] | None = None
) -> AteResult | None:
    """ATE of a run (:func:`svains.evaluation.metrics.ate`, equal to evo's) against the ground
    truth interpolated at the run's own timestamps, so association is exact; ``None`` if < 3
    poses. ``rows``: only these output rows (None: all)."""
    gt = ds.groundtruth
    if gt is None:
        return None
    t_all = result.t_ns if rows is None else result.t_ns[rows]
    x_all = result.x if rows is None else result.x[rows]
    inside, p_gt, _, q_gt = interpolate_groundtruth(gt, t_all)
    if int(inside.sum()) < 3:
        return None
    t = t_all[inside]
    args = (t, x_all[inside, 0:3], x_all[inside, 6:10], t, p_gt, q_gt)
    up_W = -np.asarray(ds.gravity_W, float)
    try:
        return ate(*args, align=align, up_W=up_W)
    except AlignmentError as exc:
        # A straight-line run leaves Umeyama's rotation undetermined: report it unaligned.
        log.warning("%s alignment impossible (%s); ATE reported without alignment", align, exc)
        return ate(*args, align="none", up_W=up_W)


def frame_rows(t_ns: NDArray[np.int64], ds: Dataset) -> NDArray[np.int64] | None:
    """Rows of the output stamps ``t_ns`` (T,) ns nearest the data's recorded stereo frames
    (``features0``), each at most ``FRAME_MATCH_NS`` away (None: no recorded frames, or fewer
    than 3 matched). A filter writes poses between frames too, carried by the IMU alone; the
    ATE over these rows compares every method at the poses ``vo`` has."""
    fs = ds.features
    if fs is None or fs.t_ns.size == 0 or t_ns.size == 0:
        return None
    _, j = matching_time_indices(np.unique(fs.t_ns) * 1e-9, t_ns * 1e-9, FRAME_MATCH_NS * 1e-9)
    rows = np.unique(j)
    return rows if rows.size >= 3 else None


def trajectory_metrics(
    result: RunResult, ds: Dataset, method: str, gps_used: bool
) -> dict[str, Any]:
    """Extra report keys for one run (see the module docstring); empty without ground truth."""
    gt = ds.groundtruth
    if gt is None or len(result.t_ns) < 3:
        return {}
    inside, p_gt, _, _ = interpolate_groundtruth(gt, result.t_ns)
    p_est = result.x[inside, 0:3]
    if len(p_est) < 3:
        return {}
    gps_ok = gps_used and ds.gps is not None and method != "vo"
    align = ate_alignment(method, gps_ok, result.world_frame)
    res = align_to_groundtruth(result, ds, align)
    if res is None:
        return {}
    ate_m = res.rmse
    path = float(np.sum(np.linalg.norm(np.diff(p_gt, axis=0), axis=1)))
    if result.world_frame == "local":
        # Static start without GPS: the raw final error measures the arbitrary initial yaw and
        # position, not the drift; take it after the ATE's alignment instead.
        final = float(np.linalg.norm(res.p_est_aligned[-1] - res.p_ref[-1]))
    else:
        final = float(np.linalg.norm(p_est[-1] - p_gt[-1]))
    rows = frame_rows(result.t_ns, ds)
    at_frames = None if rows is None else align_to_groundtruth(result, ds, align, rows)
    out: dict[str, Any] = {
        "ate_m": ate_m, "ate_alignment": res.alignment, "path_length_m": path,
        "ate_frames_m": None if at_frames is None else at_frames.rmse,
        "final_position_error_m": final,
        "final_error_pct_of_path": 100.0 * final / path if path > 0 else None,
    }
    # With configured GPS-off windows (--gps-outage, --gps-until) the report's own outage keys
    # (``run_accuracy``: gaps in the fixes the run could fuse) already cover them.
    configured = bool(result.report.get("gps_off_windows_ns"))
    outages = gps_outages(ds) if gps_ok and not configured else []
    if outages:
        errs = outage_max_errors(result.t_ns, result.x[:, 0:3], gt, outages)
        out["gps_outages_ns"] = outages
        out["outage_max_error_m"] = errs
        valid = [e for e in errs if e is not None]
        out["outage_max_error_worst_m"] = max(valid) if valid else None
    return out


def compare_owned(name: str) -> bool:
    """Whether a comparison folder's entry ``name`` is the comparison's (its tables, method
    folders, figures, temporary files): a replacing comparison drops it, and keeps the rest."""
    return (name in ("compare.md", "compare.json") or name in METHODS
            or (name.startswith("fig") and name.endswith(".png")) or name.startswith(TMP_PREFIX))


def run_methods(
    ds: Dataset,
    methods: Sequence[str] = METHODS,
    options: RunConfig | None = None,
    out_dir: Path | None = None,
    progress: Callable[[str, float], None] | None = None,
    config_text: Callable[[RunConfig], str] | None = None,
) -> dict[str, RunResult]:
    """Run each method (outputs in ``out_dir/<method>/``, with ``config.yaml`` from
    ``config_text(effective config)`` when given); reports gain ``trajectory_metrics``.

    A method that fails with a library error is logged and reported as ``{"error": message}``.
    """
    from svains.errors import SvainsError

    options = options or RunConfig()
    results: dict[str, RunResult] = {}
    for m in methods:
        if m not in METHODS:
            raise ConfigError(f"unknown method {m!r}; known: {', '.join(METHODS)}")
        sub = None if out_dir is None else Path(out_dir) / m
        prog = None if progress is None else (lambda f, m=m: progress(m, f))
        t0 = time.perf_counter()
        try:
            config = resolve_config(ds, replace(options, method=m))
            res = replay(ds, config, prog)
        except SvainsError as exc:
            log.error("%s failed: %s", m, exc)
            results[m] = RunResult(
                np.zeros(0, np.int64), np.zeros((0, 13)), np.zeros((0, 12)),
                np.zeros((0, 9, 9)), {"method": m, "error": str(exc)},
            )
            continue
        res.report.update(run_accuracy(res, ds))
        res.report.update(trajectory_metrics(res, ds, m, options.use_gps))
        smoothed = add_smoothed(res, ds, lambda r, m=m: trajectory_metrics(r, ds, m,
                                                                            options.use_gps))
        log.info("%s done in %.1f s", m, time.perf_counter() - t0)
        if sub is not None:
            with replaced_dir(sub, run_owned) as stage:  # each method's folder appears whole
                write_outputs(stage, res,
                              config_text=None if config_text is None else config_text(config))
                if smoothed is not None:
                    write_smoothed_outputs(stage, smoothed)
                write_estimated_camchain(stage, ds, res.report)
        results[m] = res
    return results


def _jsonable(o: object) -> object:
    return o.tolist() if hasattr(o, "tolist") else str(o)


_COLUMNS = (
    ("method", "method", "{}"),
    ("ATE [m]", "ate_m", "{:.3f}"),
    ("align", "ate_alignment", "{}"),
    ("pos RMSE [m]", "position_rmse_m", "{:.3f}"),
    ("vel RMSE [m/s]", "velocity_rmse_mps", "{:.3f}"),
    ("max err in outages [m]", "outage_max_error_m", "{}"),
    ("final err [% path]", "final_error_pct_of_path", "{:.2f}"),
    ("drift 50 m [%]", "drift_50m_pct", "{:.2f}"),
    ("drift 100 m [%]", "drift_100m_pct", "{:.2f}"),
    ("real-time factor", "realtime_factor", "{:.1f}"),
)


def _cell(report: dict[str, Any], key: str, fmt: str) -> str:
    v = report.get(key)
    if v is None:
        return "-"
    if isinstance(v, list):
        return ", ".join("-" if e is None else f"{e:.2f}" for e in v)
    try:
        return fmt.format(v)
    except (TypeError, ValueError):
        return str(v)


def vo_links(report: dict[str, Any]) -> int | None:
    """How many of a ``vo`` run's frames were linked to the one before (frames after the
    first, less the tracking breaks); None for the other methods."""
    vo = report.get("vo")
    if not isinstance(vo, dict) or "frames" not in vo:
        return None
    return max(int(vo["frames"]) - 1 - int(vo.get("breaks", 0)), 0)


def degraded_note(report: dict[str, Any]) -> str | None:
    """Why a method's row is not what was asked, or None: a vision method that fused no vision
    (its figures are plain INS), ``vo`` that linked fewer than two frames (no trajectory)."""
    linked = vo_links(report)
    if linked is not None and linked < 1:
        return f"no motion: {report['vo']['frames']} frame(s), none linked to the one before"
    if report.get("vision_degraded"):
        return "no vision fused: plain INS"
    return None


def comparison_markdown(reports: dict[str, dict[str, Any]], title: str) -> str:
    """The ``compare.md`` table (one row per method)."""
    head = "| " + " | ".join(c[0] for c in _COLUMNS) + " |"
    sep = "|" + "|".join("---" for _ in _COLUMNS) + "|"
    rows = []
    for m, rep in reports.items():
        if "error" in rep:
            rows.append(f"| {m} | failed: {rep['error']} |")
            continue
        note = degraded_note(rep)
        if note is not None and m == "vo":
            rows.append(f"| {m} | {note} |")
            continue
        name = m if note is None else f"{m} ({note})"
        rows.append("| " + " | ".join(_cell({**rep, "method": name}, k, f) for _, k, f in _COLUMNS)
                    + " |")
        if isinstance(rep.get("smoothed"), dict):
            # The forward-backward estimate of the same run (``--smooth``), on the next row.
            sm = {**rep["smoothed"], "method": f"{m} smoothed", "realtime_factor": None}
            rows.append("| " + " | ".join(_cell(sm, k, f) for _, k, f in _COLUMNS) + " |")
    return f"# {title}\n\n" + "\n".join([head, sep, *rows]) + "\n"


def write_comparison(out_dir: Path, results: dict[str, RunResult], title: str) -> dict[str, Any]:
    """Write ``compare.json`` (method -> report) and ``compare.md``; return the mapping."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reports = {m: r.report for m, r in results.items()}
    (out_dir / "compare.json").unlink(missing_ok=True)  # an old comparison never passes as new
    atomic_write_text(out_dir / "compare.md", comparison_markdown(reports, title))
    # compare.json last: its presence says the comparison is complete
    atomic_write_text(
        out_dir / "compare.json", json.dumps(reports, indent=2, default=_jsonable) + "\n"
    )
    return reports


def with_vision_options(options: RunConfig, **vision: Any) -> RunConfig:
    """``options`` with vision options replaced."""
    return replace(options, vision=replace(options.vision, **vision))
