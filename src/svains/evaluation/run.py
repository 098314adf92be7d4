"""One evaluated run (what ``svains run`` does): navigation, then accuracy, then output files.

:func:`svains.replay.replay` (the data set fed through a ``svains.Navigator``) produces the
estimates, covariances, timings and counters; this module adds the accuracy keys of
``report.json`` (:func:`run_accuracy`) and writes
``trajectory.tum``, ``states.csv`` and ``report.json``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.evaluation.accuracy import accuracy_report, gps_outage_report, state_errors
from svains.evaluation.extrinsics import CAMCHAIN_NAME, write_estimated_camchain
from svains.evaluation.reference_tilt import estimate_reference_gravity, leveling_rotation
from svains.evaluation.run_record import PLOT_NAMES
from svains.navigation.options import RunConfig
from svains.navigation.outputs import RunResult
from svains.navigation.smoothing import smoothed_result
from svains.outputs import TMP_PREFIX, replaced_dir
from svains.replay import replay, resolve_config
from svains.replay.writers import (
    RUN_FILES,
    write_outputs,
    write_report,
    write_smoothed_outputs,
)


def errors_alignment_for(result: RunResult) -> str:
    """Alignment applied before the per-state error keys of ``result``.

    ``none`` when the run's world frame is the ground truth's (``world_frame`` ``groundtruth``
    or ``gps``); otherwise the degrees of freedom the method cannot observe: ``posyaw`` (yaw and
    translation) for a filter, whose roll and pitch follow gravity, ``start_position`` (the
    first state's position) for one whose heading a magnetometer fixed, ``se3`` for pure VO.
    """
    if result.world_frame in ("groundtruth", "gps"):
        return "none"
    if result.report.get("method") == "vo":
        return "se3"
    return "start_position" if _fused(result, "mag") > 0 else "posyaw"


def _fused(result: RunResult, sensor: str) -> int:
    """How many of ``sensor``'s measurements the run fused (``report.json``'s counts)."""
    seen = result.report.get("measurements") or {}
    return int((seen.get(sensor) or {}).get("fused", 0))


def _up_W(dataset: Dataset) -> NDArray[np.float64]:
    """Unit up vector (3,) of the data set's world frame: against gravity."""
    g_W = np.asarray(dataset.gravity_W, dtype=float)
    return -g_W / np.linalg.norm(g_W)


def reference_leveling(
    result: RunResult, dataset: Dataset
) -> tuple[NDArray[np.float64] | None, dict[str, Any]]:
    """``R_W_Wref`` (3, 3) levelling the ground truth before the errors of ``result`` (None:
    left as it is) and the report keys ``reference_tilt_deg`` (the tilt removed, deg, or None)
    and ``reference_gravity`` (:class:`ReferenceGravity` as a dict, None when not estimated:
    no IMU or ground truth).

    The tilt is removed only when :func:`estimate_reference_gravity` finds it significant and
    before a ``posyaw`` alignment, which cannot remove it. With ``none`` the run's world is the
    reference's by construction (started from it, or fixed by GPS); ``se3`` removes a tilt
    itself.
    """
    keys: dict[str, Any] = {"reference_tilt_deg": None, "reference_gravity": None}
    est = estimate_reference_gravity(dataset)
    if est is None:
        return None, keys
    keys["reference_gravity"] = est.as_report()
    if not est.significant or errors_alignment_for(result) != "posyaw":
        return None, keys
    keys["reference_tilt_deg"] = est.tilt_deg
    return leveling_rotation(est.g_Wr, dataset.gravity_W), keys


def _frame_is_the_starts(result: RunResult) -> bool:
    """Whether the run's world is the one its first state defines: no magnetometer (an absolute
    heading, which corrects the start's yaw within a fraction of a second) and no sonar (an
    absolute height) fused, no sonar-set start height. Otherwise the first state is no anchor
    (a user's probe: a consistent run, NEES 7.7, anchored on its first state 1.25e5)."""
    fused = _fused(result, "mag") + _fused(result, "sonar")
    init = result.report.get("init") or {}
    return fused == 0 and "height_from_sonar_m" not in init


def run_accuracy(result: RunResult, dataset: Dataset) -> dict[str, Any]:
    """The accuracy keys of ``report.json`` for ``result`` (see ``docs/formats.md``): ATE,
    RMSE and NEES after :func:`errors_alignment_for` (against the reference levelled by
    :func:`reference_leveling`), GPS-outage figures when GPS was used."""
    R_W_Wref, tilt_keys = reference_leveling(result, dataset)
    out = accuracy_report(
        result.t_ns, result.x, result.P9, dataset.groundtruth,
        errors_alignment=errors_alignment_for(result), up_W=_up_W(dataset), R_W_Wref=R_W_Wref,
    )  # fmt: skip
    out.update(tilt_keys)
    if not result.has_covariance:
        # No covariance (VO): NEES and the 3σ coverage are not defined.
        out["nees_mean"] = None
        out["nees_blocks"] = None
        for key in ("nees_blocks_dof", "position_within_3sigma"):
            out.pop(key, None)
    if not result.has_covariance or not _frame_is_the_starts(result):
        out.pop("nees_start_anchored", None)
        out.pop("nees_blocks_start_anchored", None)
    if dataset.groundtruth is not None and dataset.gps is not None and result.gps_used:
        outages = gps_outage_report(
            result.t_ns, result.x, result.std, fused_gps_times(result, dataset.gps.t_ns),
            dataset.groundtruth,
        )
        out.update(outages)
        if outages["gps_outages"]:
            # Issue 6's key: the largest position error inside each GPS outage (m).
            out["outage_max_error_m"] = [o["error_max_m"] for o in outages["gps_outages"]]
    return out


def add_smoothed(
    result: RunResult, dataset: Dataset,
    extra: Callable[[RunResult], dict[str, Any]] | None = None,
) -> RunResult | None:
    """Smooth ``result`` when it kept a history (``smoother.enabled``): ``result.smoothed``
    and ``report["smoothed"]`` (the accuracy keys of :func:`run_accuracy`, those of ``extra``,
    and ``navigation.smoothing``'s cost keys); None without a history."""
    if result.history is None:
        return None
    smoothed = smoothed_result(result)
    result.smoothed = smoothed
    keys = run_accuracy(smoothed, dataset)
    if extra is not None:
        keys.update(extra(smoothed))
    result.report["smoothed"] = {**keys, **smoothed.report["smoothing"]}
    return smoothed


def fused_gps_times(result: RunResult, t_gps_ns: NDArray[np.int64]) -> NDArray[np.int64]:
    """GPS fix times (N,) ns that the run could fuse: inside the span of its logged states and
    outside the configured GPS-off windows (``--gps-outage``, ``--gps-until``), so those windows,
    and the stretches before its first and after its last fix, count as outages."""
    t = np.asarray(t_gps_ns, dtype=np.int64)
    # fixes before --start or after --duration were never fed: counted, they made the first
    # outage start 6 s before the run and the last one end 5 s after it, unmarked (a probe)
    keep = ((t >= result.t_ns[0]) & (t <= result.t_ns[-1]) if len(result.t_ns)
            else np.zeros(t.size, dtype=bool))  # fmt: skip
    for a, b in result.report.get("gps_off_windows_ns", []):
        keep &= ~((t >= a) & (t < b))
    return t[keep]


def nees_series(
    result: RunResult, dataset: Dataset, start_anchored: bool = False
) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """Per logged state: ``t_ns`` (N,) and NEES (N,) of (p, v, δθ), 9 dof, after
    :func:`errors_alignment_for` (the series whose mean is ``report.json``'s ``nees_mean``), or
    with ``start_anchored`` after the first state's yaw and position (``nees_start_anchored``'s;
    None where the run's report has none: not posyaw, or a frame its start does not define);
    ``None`` without a covariance or ground truth."""
    if not result.has_covariance:
        return None
    if start_anchored and not (errors_alignment_for(result) == "posyaw"
                               and _frame_is_the_starts(result)):  # fmt: skip
        return None
    errs = state_errors(
        result.t_ns, result.x, result.P9, dataset.groundtruth,
        "start" if start_anchored else errors_alignment_for(result),
        up_W=_up_W(dataset), R_W_Wref=reference_leveling(result, dataset)[0],
    )  # fmt: skip
    return None if errs is None else (errs.t_ns, errs.nees)


def run_owned(name: str) -> bool:
    """Whether a run folder's entry ``name`` belongs to the run (its outputs, its figures, an
    interrupted write's temporary file), so that a replacing run drops it; anything else in
    the folder (a user's notes) is kept."""
    return name in RUN_FILES or name in PLOT_NAMES or name == CAMCHAIN_NAME or (
        name.startswith(TMP_PREFIX))


def run_method(
    dataset: Dataset,
    method: str | None = None,
    options: RunConfig | None = None,
    out_dir: Path | None = None,
    progress: Callable[[float], None] | None = None,
    config_text: str | None = None,
    started_s: float | None = None,
) -> RunResult:
    """Replay ``dataset`` through the estimator with ``options`` (a ``RunConfig``; ``method``,
    when given, replaces ``options.method``), add the accuracy keys to the report, and
    ``wall_end_to_end_s`` / ``realtime_factor_end_to_end``: from ``started_s``
    (``time.perf_counter()`` when the caller began, e.g. before loading the data set; default
    this call) to the last output file but ``report.json``.

    With ``out_dir``, write ``trajectory.tum``, ``states.csv``, ``report.json``, the other output
    files, ``config.yaml`` from ``config_text`` when given, and ``camchain_estimated.yaml`` when
    the run estimated the camera rotation or time offset: the folder is replaced whole at the
    end, or left untouched on a failure. The configuration is first resolved against the data set
    (``svains.replay.resolve_config``)."""
    t0 = time.perf_counter() if started_s is None else started_s
    config = options or RunConfig()
    if method is not None and method != config.method:
        config = replace(config, method=method)  # type: ignore[arg-type]
    config = resolve_config(dataset, config)
    result = replay(dataset, config, progress)
    result.report.update(run_accuracy(result, dataset))
    smoothed = add_smoothed(result, dataset)
    if out_dir is not None:
        # The folder is replaced whole at the end: a previous run's files never sit beside these.
        with replaced_dir(out_dir, run_owned) as stage:
            write_outputs(stage, result, config_text=config_text, report=False)
            if smoothed is not None:
                write_smoothed_outputs(stage, smoothed)
            write_estimated_camchain(stage, dataset, result.report)
            _end_to_end(result.report, t0)
            write_report(stage, result.report)
    else:
        _end_to_end(result.report, t0)
    return result


def _end_to_end(report: dict[str, Any], t0: float) -> None:
    """The wall time since ``t0`` (``time.perf_counter()``) and the data's span over it: what
    a user waits for, where ``wall_s`` is the estimator's alone (a 30-minute ``3d`` flight:
    25x real time reported, 16x from the command to its files)."""
    wall = time.perf_counter() - t0
    report["wall_end_to_end_s"] = wall
    duration = report.get("data_duration_s")
    report["realtime_factor_end_to_end"] = duration / wall if duration and wall > 0 else None
