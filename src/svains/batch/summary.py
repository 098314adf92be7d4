"""A campaign's tables: ``summary.csv`` (one row per run), ``summary.md`` (statistics per method
and configuration, the NEES consistency test) and ``consistency.csv`` (average NEES per step).

``summary.csv`` columns: the task's parameters (``task_id``, ``source``, ``kind``, ``method``,
``config``, ``seed``, ``replicate``, ``status``, ``error``), its data parameters (``data.*``) and
run settings (``settings.*``), then every ``report.json`` key flattened with dots (lists as JSON).
Floats are written with ``repr``, so equal runs give equal rows.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from svains.batch.consistency import NeesTest, nees_test
from svains.batch.spec import CampaignSpec, Task, flatten
from svains.batch.store import NEES_FILES, read_marker, read_nees, read_report

GroupKey = tuple[str, str, str]  # (source, config, method)


def _cell(value: Any) -> Any:
    if isinstance(value, list | tuple):
        return json.dumps(value)
    return "" if value is None else value


def summary_rows(out_dir: Path, tasks: Sequence[Task]) -> list[dict[str, Any]]:
    """One row per task (``status`` ``pending`` for a run without a marker)."""
    rows = []
    for task in tasks:
        marker = read_marker(out_dir, task) or {}
        status = marker.get("status", "pending")
        row: dict[str, Any] = {
            "task_id": task.task_id, "source": task.source, "kind": task.kind,
            "method": task.method, "config": task.config, "seed": task.seed,
            "replicate": task.replicate, "status": status, "error": marker.get("error"),
        }  # fmt: skip
        row.update({f"data.{k}": v for k, v in flatten(task.data).items()})
        row.update({f"settings.{k}": v for k, v in task.settings.items()})
        if status == "ok":
            row.update(flatten(read_report(out_dir, task)))
        rows.append({k: _cell(v) for k, v in row.items()})
    return rows


def write_summary_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(columns), restval="")
        writer.writeheader()
        writer.writerows(rows)


def group_rows(rows: list[dict[str, Any]]) -> dict[GroupKey, list[dict[str, Any]]]:
    out: dict[GroupKey, list[dict[str, Any]]] = {}
    for row in rows:
        out.setdefault((row["source"], row["config"], row["method"]), []).append(row)
    return out


def metric_values(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    """Finite numeric values of ``key`` over the finished rows."""
    vals = [r.get(key) for r in rows if r["status"] == "ok"]
    out = [float(v) for v in vals if isinstance(v, int | float) and not isinstance(v, bool)]
    return np.array([v for v in out if math.isfinite(v)])


def unknown_metrics(metrics: Sequence[str], rows: list[dict[str, Any]]) -> dict[str, list[str]]:
    """The ``metrics`` no finished run's report holds (a misspelt key: ``ate`` for ``ate_m``),
    each with the report keys closest to it; empty before any run finished."""
    keys: set[str] = set()
    for r in rows:
        if r["status"] == "ok":
            keys.update(k for k, v in r.items() if isinstance(v, int | float))
    if not keys:
        return {}
    return {m: difflib.get_close_matches(m, sorted(keys), n=3, cutoff=0.5)
            for m in metrics if m not in keys}  # fmt: skip


def _stats_table(groups: dict[GroupKey, list[dict[str, Any]]], key: str) -> list[str]:
    lines = [f"### `{key}`", "", "| source | config | method | N | mean | median | 90th pct |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for (source, config, method), rows in groups.items():
        v = metric_values(rows, key)
        if v.size == 0:
            continue
        lines.append(f"| {source} | {config} | {method} | {v.size} | {v.mean():.4g} | "
                     f"{np.median(v):.4g} | {np.percentile(v, 90):.4g} |")  # fmt: skip
    return [*lines, ""] if len(lines) > 4 else []


def nees_tests(
    out_dir: Path, tasks: Sequence[Task], rows: list[dict[str, Any]]
) -> dict[GroupKey, NeesTest]:
    """The consistency test of every (source, config, method) group with NEES series."""
    ok = {r["task_id"] for r in rows if r["status"] == "ok"}
    series: dict[GroupKey, list[Any]] = {}
    for task in tasks:
        for kind in NEES_FILES:
            s = read_nees(out_dir, task, kind) if task.task_id in ok else None
            if s is not None:
                # A smoothed run's own test, as a method "<method> smoothed"; a local run's in
                # the frame its start defines, "<method> start-anchored" (the whole-run posyaw
                # fit read a consistent GPS-denied ins 41x overconfident: a probe)
                method = f"{task.method} {kind}" if kind else task.method
                series.setdefault((task.source, task.config, method), []).append(s)
    tests = {key: nees_test(s) for key, s in series.items()}
    return {k: t for k, t in tests.items() if t is not None}


def _nees_table(tests: dict[GroupKey, NeesTest]) -> list[str]:
    lines = [
        "## Monte Carlo consistency (NEES, 9 dof: position, velocity, attitude)", "",
        "Average NEES over the N runs; 95 % two-sided χ² bounds for an average of N runs. "
        "Overall: averaged over the runs and all K common steps; the second interval assumes "
        "independent steps (too narrow, steps are correlated).", "",
        "| source | config | method | N | K steps | steps inside | overall avg NEES | "
        "95 % bounds (N runs) | verdict | bounds (N·K) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for (source, config, method), t in tests.items():
        lo, hi = t.overall_bounds_runs
        slo, shi = t.overall_bounds_steps
        lines.append(
            f"| {source} | {config} | {method} | {t.n_runs} | {len(t.t_ns)} | "
            f"{100 * t.fraction_inside:.1f} % | {t.overall:.3f} | [{lo:.3f}, {hi:.3f}] | "
            f"{t.verdict} | [{slo:.3f}, {shi:.3f}] |"
        )
    return [*lines, ""]


def write_consistency_csv(path: Path, tests: dict[GroupKey, NeesTest]) -> None:
    with open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["source", "config", "method", "t_ns", "n_runs", "nees_avg", "lower", "upper"])
        for (source, config, method), t in tests.items():
            for tk, v in zip(t.t_ns, t.nees_avg, strict=True):
                w.writerow([source, config, method, int(tk), t.n_runs, repr(float(v)),
                            repr(t.bounds[0]), repr(t.bounds[1])])  # fmt: skip


def summary_markdown(
    spec: CampaignSpec, rows: list[dict[str, Any]], tests: dict[GroupKey, NeesTest],
    figures: Sequence[str] = (),
) -> str:
    """``summary.md``: run counts, the statistics of ``spec.metrics`` per group, the NEES test,
    failures and the figures' file names."""
    groups = group_rows(rows)
    count = {s: sum(r["status"] == s for r in rows) for s in ("ok", "failed", "pending")}
    out = [f"# Campaign `{spec.name}`", ""]
    if spec.description:
        out += [spec.description.strip(), ""]
    out += [f"{len(rows)} runs: {count['ok']} finished, {count['failed']} failed, "
            f"{count['pending']} not run.", "", "## Statistics per method and configuration", ""]
    for key in spec.metrics:
        out += _stats_table(groups, key)
    for key, close in unknown_metrics(spec.metrics, rows).items():
        out += [f"Metric `{key}` is in no finished run's report"
                + (f" (closest: {', '.join(f'`{c}`' for c in close)})" if close else ""), ""]
    if tests:
        out += _nees_table(tests)
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:
        out += ["## Failed runs", ""] + [f"- `{r['task_id']}`: {r['error']}" for r in failed] + [""]
    if figures:
        out += ["## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    return "\n".join(out)
