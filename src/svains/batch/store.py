"""A campaign's folder: one sub-folder per run, marked finished atomically.

``DIR/runs/<task_id>/`` holds what ``svains run`` writes (``trajectory.tum``, ``states.csv``,
``report.json``), ``nees.csv`` (``t_ns,nees`` per logged state; ``nees_smoothed.csv`` the
same for a smoothed run, ``nees_start_anchored.csv`` and ``nees_smoothed_start_anchored.csv``
in the frame the start defines where the report has ``nees_start_anchored``) and
``result.json``: the task's parameters and its status (``ok``, or ``failed`` with the error
and traceback). The folder is built beside its final place and renamed into it whole. A run
with an ``ok`` marker is finished and is skipped when the campaign is run again; a failed one
is run again.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.batch.spec import Task
from svains.batch.task import TaskResult
from svains.navigation.outputs import RunResult
from svains.outputs import replaced_dir
from svains.replay.writers import write_outputs

MARKER = "result.json"


def run_dir(out_dir: Path, task: Task) -> Path:
    return Path(out_dir) / "runs" / task.task_id


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old file or the whole new one."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def read_marker(out_dir: Path, task: Task) -> dict[str, Any] | None:
    """The run's ``result.json`` content, ``None`` if it never finished."""
    path = run_dir(out_dir, task) / MARKER
    if not path.is_file():
        return None
    try:
        marker: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None  # unreadable marker: run it again
    return marker


def is_finished(out_dir: Path, task: Task) -> bool:
    marker = read_marker(out_dir, task)
    return marker is not None and marker.get("status") == "ok"


def write_result(out_dir: Path, task: Task, result: TaskResult) -> None:
    """Write a finished task's files and its marker into a staging folder that then replaces
    the run's folder whole (a re-run task never mixes its files with the previous attempt's)."""
    marker: dict[str, Any] = {"task_id": task.task_id, "status": result.status,
                              "replicate": task.replicate, **task.params()}  # fmt: skip
    with replaced_dir(run_dir(out_dir, task)) as d:
        if result.status == "ok":
            assert result.report is not None and result.t_ns is not None  # set for status ok
            assert result.x is not None and result.std is not None
            run = RunResult(result.t_ns, result.x, result.std, np.zeros((0, 9, 9)), result.report)
            write_outputs(d, run)
            for name, series in (("nees.csv", result.nees_series()),
                                 ("nees_smoothed.csv", result.smoothed_nees),
                                 ("nees_start_anchored.csv", result.anchored_nees),
                                 ("nees_smoothed_start_anchored.csv",
                                  result.smoothed_anchored_nees)):
                if series is not None:
                    rows = "".join(f"{int(t)},{v:.9g}\n" for t, v in zip(*series, strict=True))
                    write_atomic(d / name, "t_ns,nees\n" + rows)
        else:
            marker.update(error=result.error, traceback=result.traceback)
        write_atomic(d / MARKER, json.dumps(marker, indent=2) + "\n")


def read_report(out_dir: Path, task: Task) -> dict[str, Any]:
    report: dict[str, Any] = json.loads(
        (run_dir(out_dir, task) / "report.json").read_text(encoding="utf-8")
    )
    return report


# the NEES series a run may keep: their file beside its outputs, by kind
NEES_FILES = {"": "nees.csv", "smoothed": "nees_smoothed.csv",
              "start-anchored": "nees_start_anchored.csv",
              "smoothed start-anchored": "nees_smoothed_start_anchored.csv"}


def read_nees(
    out_dir: Path, task: Task, kind: str = ""
) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """``t_ns`` (N,) and NEES (N,) of a finished run (``kind`` a key of ``NEES_FILES``:
    ``smoothed``, its smoothed estimate's; ``start-anchored``, in the frame its start defines;
    both), ``None`` if it has none."""
    path = run_dir(out_dir, task) / NEES_FILES[kind]
    if not path.is_file():
        return None
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return data[:, 0].astype(np.int64), data[:, 1]
