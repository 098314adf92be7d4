"""One evaluated run (what ``svains run`` does): navigation, then accuracy, then output files.

:func:`svains.replay.replay` (the data set fed through a ``svains.Navigator``) produces the
estimates, covariances, timings and counters; this module adds the accuracy keys of
``report.json`` (:func:`run_accuracy`) and writes
``trajectory.tum``, ``states.csv`` and ``report.json``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.evaluation.accuracy import accuracy_report, gps_outage_report, state_errors
from svains.evaluation.extrinsics import write_estimated_camchain
from svains.navigation.options import RunConfig
from svains.navigation.outputs import RunResult
from svains.replay import replay, resolve_config
from svains.replay.writers import write_outputs


def errors_alignment_for(result: RunResult) -> str:
    """Alignment applied before the per-state error keys of ``result``.

    ``none`` when the run's world frame is the ground truth's (``world_frame`` ``groundtruth``
    or ``gps``); otherwise the degrees of freedom the method cannot observe: ``posyaw`` (yaw and
    translation) for a filter, whose roll and pitch follow gravity, ``se3`` for pure VO.
    """
    if result.world_frame in ("groundtruth", "gps"):
        return "none"
    return "se3" if result.report.get("method") == "vo" else "posyaw"


def _up_W(dataset: Dataset) -> NDArray[np.float64]:
    """Unit up vector (3,) of the data set's world frame: against gravity."""
    g_W = np.asarray(dataset.gravity_W, dtype=float)
    return -g_W / np.linalg.norm(g_W)


def run_accuracy(result: RunResult, dataset: Dataset) -> dict[str, Any]:
    """The accuracy keys of ``report.json`` for ``result`` (see ``docs/formats.md``): ATE,
    RMSE and NEES after :func:`errors_alignment_for`, GPS-outage figures when GPS was used."""
    out = accuracy_report(
        result.t_ns, result.x, result.P9, dataset.groundtruth,
        errors_alignment=errors_alignment_for(result), up_W=_up_W(dataset),
    )  # fmt: skip
    if not result.has_covariance:
        # No covariance (VO): NEES and the 3σ coverage are not defined.
        out["nees_mean"] = None
        out.pop("position_within_3sigma", None)
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


def fused_gps_times(result: RunResult, t_gps_ns: NDArray[np.int64]) -> NDArray[np.int64]:
    """GPS fix times (N,) ns that the run could fuse: those outside the configured GPS-off
    windows (``--gps-outage``, ``--gps-until``), so those windows count as outages."""
    t = np.asarray(t_gps_ns, dtype=np.int64)
    keep = np.ones(t.size, dtype=bool)
    for a, b in result.report.get("gps_off_windows_ns", []):
        keep &= ~((t >= a) & (t < b))
    return t[keep]


def nees_series(
    result: RunResult, dataset: Dataset
) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """Per logged state: ``t_ns`` (N,) and NEES (N,) of (p, v, δθ), 9 dof, after
    :func:`errors_alignment_for` (the series whose mean is ``report.json``'s ``nees_mean``);
    ``None`` without a covariance or ground truth."""
    if not result.has_covariance:
        return None
    errs = state_errors(
        result.t_ns, result.x, result.P9, dataset.groundtruth, errors_alignment_for(result),
        up_W=_up_W(dataset),
    )
    return None if errs is None else (errs.t_ns, errs.nees)


def run_method(
    dataset: Dataset,
    method: str | None = None,
    options: RunConfig | None = None,
    out_dir: Path | None = None,
    progress: Callable[[float], None] | None = None,
    config_text: str | None = None,
) -> RunResult:
    """Replay ``dataset`` through the estimator with ``options`` (a ``RunConfig``; ``method``,
    when given, replaces ``options.method``), add the accuracy keys to the report; write
    ``trajectory.tum``, ``states.csv`` and ``report.json`` (and the other output files, and
    ``camchain_estimated.yaml`` when the run estimated the camera rotation) into ``out_dir`` if
    given, with ``config_text`` as ``config.yaml`` when given. The configuration
    is first resolved against the data set (``svains.replay.resolve_config``)."""
    config = options or RunConfig()
    if method is not None and method != config.method:
        config = replace(config, method=method)  # type: ignore[arg-type]
    config = resolve_config(dataset, config)
    result = replay(dataset, config, progress)
    result.report.update(run_accuracy(result, dataset))
    if out_dir is not None:
        write_outputs(Path(out_dir), result, config_text=config_text)
        write_estimated_camchain(Path(out_dir), dataset, result.report)
    return result
