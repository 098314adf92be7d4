"""Run one campaign task where it lands (a Dask worker or this process): :func:`run_task`.

Simulated data are generated inside the task from its seed, in a temporary folder of the
machine that runs it (feature-level or rendered, as the scenario says), so workers need no shared
disk for them; a real data set is read from its path, which every worker must see. The result
travels back as plain data; the submitting process writes every file.
"""

from __future__ import annotations

import logging
import tempfile
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.batch.settings import run_options_from_settings
from svains.batch.spec import Task
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.compare import trajectory_metrics
from svains.evaluation.run import nees_series, run_method
from svains.replay import resolve_config
from svains.sim import SimConfig, simulate
from svains.threads import limit_threads

log = logging.getLogger(__name__)

# report.json keys that measure the machine, not the run: they differ between any two runs.
TIMING_KEYS: tuple[str, ...] = ("wall_s", "realtime_factor", "wall_end_to_end_s",
                                "realtime_factor_end_to_end")


@dataclass
class TaskResult:
    """What a task sends back: ``status`` ``ok`` or ``failed`` (``error``: the exception's type
    and message, ``traceback``), the ``report.json`` content, the logged states (``t_ns`` (T,),
    ``x`` (T, nx), ``std`` (T, ndx)) and the per-state NEES (``nees_t_ns``, ``nees``; None
    without covariance or ground truth)."""

    task_id: str
    status: str
    report: dict[str, Any] | None = None
    t_ns: NDArray[np.int64] | None = None
    x: NDArray[np.float64] | None = None
    std: NDArray[np.float64] | None = None
    nees_t_ns: NDArray[np.int64] | None = None
    nees: NDArray[np.float64] | None = None
    error: str | None = None
    traceback: str | None = None
    # ``(t_ns, nees)`` of the smoothed estimate (``smoother.enabled``), None without.
    smoothed_nees: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
    # ``(t_ns, nees)`` in the frame the start defines (``nees_start_anchored``), the filter's
    # and the smoothed estimate's; None without.
    anchored_nees: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
    smoothed_anchored_nees: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None

    def nees_series(self) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
        """``(nees_t_ns, nees)``, None without."""
        if self.nees is None or self.nees_t_ns is None:
            return None
        return self.nees_t_ns, self.nees


def task_dataset(task: Task, tmp: Path) -> Dataset:
    """The task's data: its scenario simulated with its seed into ``tmp``, or its data set (with
    features simulated along the ground truth when ``synthetic_features_hz`` is set)."""
    if task.kind == "scenario":
        cfg = SimConfig.from_dict({**task.data, "seed": task.seed})
        return load_dataset(simulate(cfg, tmp / "data"))
    from svains.datasets.rosbag import parse_topic_roles

    ds = load_dataset(task.data["path"], calib=task.data.get("calib"),
                      imu_calib=task.data.get("imu_calib"),
                      topics=parse_topic_roles(task.data.get("topics")))
    hz = task.data.get("synthetic_features_hz")
    if hz is None:
        return ds
    from svains.replay.synthetic import with_synthetic_features

    return with_synthetic_features(ds, rate_hz=float(hz), seed=int(task.seed or 0))


def _run(task: Task, ds: Dataset) -> TaskResult:
    # The same per-method noise treatment as ``svains run`` and ``svains compare``.
    options = resolve_config(
        ds, replace(run_options_from_settings(task.settings), method=task.method)  # type: ignore[arg-type]
    )
    result = run_method(ds, task.method, options)
    # ``svains compare``'s keys (ATE with the alignment that fits the run, final error).
    result.report.update(trajectory_metrics(result, ds, task.method, options.use_gps))
    nees = nees_series(result, ds)
    return TaskResult(
        task.task_id, "ok", result.report, result.t_ns, result.x, result.std,
        None if nees is None else nees[0], None if nees is None else nees[1],
        smoothed_nees=None if result.smoothed is None else nees_series(result.smoothed, ds),
        anchored_nees=nees_series(result, ds, start_anchored=True),
        smoothed_anchored_nees=(None if result.smoothed is None
                                else nees_series(result.smoothed, ds, start_anchored=True)),
    )  # fmt: skip


def _failed(task: Task, exc: BaseException) -> TaskResult:
    log.warning("task %s failed: %s: %s", task.task_id, type(exc).__name__, exc)
    return TaskResult(task.task_id, "failed", error=f"{type(exc).__name__}: {exc}",
                      traceback=traceback.format_exc())  # fmt: skip


def run_task(task: Task, dataset: Dataset | None = None) -> TaskResult:
    """Run one task on ``dataset`` (its data, already loaded) or on the data it loads or
    simulates itself. Never raises for a failing run: its error is returned, so one bad run
    does not stop a campaign. Linear algebra runs on one thread (one task per core, and results
    that do not depend on the machine's BLAS threading)."""
    try:
        with limit_threads(1):
            if dataset is not None:
                return _run(task, dataset)
            with tempfile.TemporaryDirectory(prefix="svains-task-") as tmp:
                return _run(task, task_dataset(task, Path(tmp)))
    except Exception as exc:  # a failed run is a result, whatever raised
        return _failed(task, exc)


def run_group(tasks: Sequence[Task]) -> list[TaskResult]:
    """Run tasks that share their data (equal :meth:`Task.data_key`): the data are simulated or
    loaded once, then each run goes through :func:`run_task`. A run's result is the same as
    alone (the runs never modify the data set)."""
    if len({t.data_key() for t in tasks}) > 1:
        raise ValueError("run_group needs tasks with one data key")
    try:
        # one thread per library whatever the submitting shell's SVAINS_THREADS (OpenCV too:
        # SVAINS_THREADS=8 ran a 2-worker campaign in 22 s against 10 s)
        with limit_threads(1), tempfile.TemporaryDirectory(prefix="svains-") as tmp:
            ds = task_dataset(tasks[0], Path(tmp))
            return [run_task(t, ds) for t in tasks]
    except Exception as exc:  # the data could not be made: every run of the group failed
        return [_failed(t, exc) for t in tasks]
