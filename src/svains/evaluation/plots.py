"""``svains plot RUN_DIR``: a run's consistency figures as PNG (matplotlib object API).

- ``errors.png``: position, velocity and attitude error per axis against time with the filter's
  ±3σ bounds (after the run's ``errors_alignment``), and the smoothed estimate's with its own
  bounds when the run was smoothed (``states_smoothed.csv``);
- ``nees.png``: NEES over time (9 dof, diagonal covariance from ``states.csv``) with its 95 %
  chi-square interval (and the smoothed estimate's);
- ``measurements.png``: per sensor, updates fused and rejected (cumulative) over time, from
  ``updates.csv``; a run without that log gets the totals of ``report.json``;
- ``time_offset.png`` (runs that estimated the camera-IMU time offset): the estimate over time
  with its ±3σ band, from ``report.json``'s ``vision.time_offset_history``; with the data set,
  the simulator's true offset (``scenario.yaml``) as a line.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from scipy.stats import chi2

from svains.datasets.types import Dataset
from svains.evaluation.run_record import RunErrors, RunRecord, read_run, run_errors

log = logging.getLogger(__name__)

_ERR_ROWS = (("position", "m", 1.0), ("velocity", "m/s", 1.0), ("attitude", "deg", 180 / np.pi))


@dataclass(frozen=True)
class PlotFile:
    """One written PNG and the titles of its panels, in reading order."""

    path: Path
    panels: tuple[str, ...]


def _save(fig: Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return path


def plot_errors(err: RunErrors, path: Path, smoothed: RunErrors | None = None) -> PlotFile:
    """3x3 panels: error per axis (x, y, z) of position, velocity, attitude with ±3σ; the
    ``smoothed`` estimate's errors and bounds over them when given."""
    t_s = (err.t_ns - err.t_ns[0]) * 1e-9
    fig = Figure(figsize=(12, 8))
    axes = fig.subplots(3, 3, sharex=True)
    titles = []
    for r, (name, unit, scale) in enumerate(_ERR_ROWS):
        for c, axis in enumerate("xyz"):
            ax: Axes = axes[r, c]
            k = 3 * r + c
            bound = 3.0 * err.std[:, k] * scale
            ax.fill_between(t_s, -bound, bound, color="tab:blue", alpha=0.2, label="±3 sigma")
            ax.plot(t_s, err.e[:, k] * scale, color="tab:red", lw=1.0, label="error")
            if smoothed is not None:
                ts = (smoothed.t_ns - err.t_ns[0]) * 1e-9
                sb = 3.0 * smoothed.std[:, k] * scale
                ax.fill_between(ts, -sb, sb, color="tab:orange", alpha=0.3,
                                label="smoothed ±3 sigma")  # fmt: skip
                ax.plot(ts, smoothed.e[:, k] * scale, color="tab:purple", lw=1.0,
                        label="smoothed error")  # fmt: skip
            title = f"{name} {axis} [{unit}]"
            ax.set_title(title)
            titles.append(title)
            if r == 2:
                ax.set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper left")
    aligned = "unaligned" if err.alignment == "none" else f"after {err.alignment} alignment"
    fig.suptitle(f"errors {aligned}, with the filter's ±3 sigma"
                 + (" (and the smoother's)" if smoothed is not None else ""))
    return PlotFile(_save(fig, path), tuple(titles))


def plot_nees(
    err: RunErrors, path: Path, dof: int = 9, smoothed: RunErrors | None = None
) -> PlotFile:
    """NEES against time with the 95 % interval of a chi-square with ``dof`` degrees (and the
    ``smoothed`` estimate's NEES when given)."""
    t_s = (err.t_ns - err.t_ns[0]) * 1e-9
    fig = Figure(figsize=(10, 4))
    ax = fig.subplots()
    lo, hi = chi2.ppf([0.025, 0.975], dof)
    ax.axhspan(lo, hi, color="tab:green", alpha=0.15, label=f"95 % interval, {dof} dof")
    ax.axhline(dof, color="tab:green", lw=1.0)
    ax.plot(t_s, err.nees, color="tab:blue", lw=1.0, label="NEES (diagonal covariance)")
    # (report.json's ``nees_mean`` takes the full covariance: a user's probe read this mean,
    # 53.08, as that figure, 79.2)
    title = f"NEES over time, diagonal covariance (mean {np.nanmean(err.nees):.2f})"
    if smoothed is not None:
        ax.plot((smoothed.t_ns - err.t_ns[0]) * 1e-9, smoothed.nees, color="tab:purple", lw=1.0,
                label="smoothed NEES")  # fmt: skip
        title = (f"NEES over time, diagonal covariance (mean {np.nanmean(err.nees):.2f}, smoothed "
                 f"{np.nanmean(smoothed.nees):.2f})")  # fmt: skip
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_title(title)
    ax.legend(loc="upper right")
    return PlotFile(_save(fig, path), (title,))


def plot_measurements(rec: RunRecord, path: Path) -> PlotFile:
    """Per sensor: cumulative fused and rejected updates over time (``updates.csv``), or the
    totals of ``report.json`` as bars when the run has no per-update log."""
    fig = Figure(figsize=(10, 4))
    u = rec.updates
    if u is None or u["t_ns"].size == 0:
        ax = fig.subplots()
        meas = rec.report.get("measurements") or {}
        names = list(meas)
        x = np.arange(len(names))
        ax.bar(x - 0.2, [meas[n]["fused"] for n in names], 0.4, label="fused")
        ax.bar(x + 0.2, [meas[n]["rejected"] for n in names], 0.4, label="rejected")
        ax.set_xticks(x, names)
        ax.legend()
        title = "fused/rejected totals (report.json; no updates.csv in this run)"
        ax.set_title(title)
        return PlotFile(_save(fig, path), (title,))
    sensors = sorted(set(u["sensor"].tolist()))
    axes = np.atleast_1d(fig.subplots(len(sensors), 1, sharex=True, squeeze=False)[:, 0])
    t0 = int(rec.t_ns[0]) if rec.t_ns.size else int(u["t_ns"].min())
    titles = []
    for ax, s in zip(axes, sensors, strict=True):
        sel = u["sensor"] == s
        t_s = (u["t_ns"][sel] - t0) * 1e-9
        ok = u["accepted"][sel] > 0.5
        ax.step(t_s, np.cumsum(ok), where="post", label="fused", color="tab:blue")
        ax.step(t_s, np.cumsum(~ok), where="post", label="rejected", color="tab:red")
        title = f"{s}: {int(ok.sum())} fused, {int((~ok).sum())} rejected"
        ax.set_title(title)
        titles.append(title)
        ax.legend(loc="upper left")
    axes[-1].set_xlabel("time [s]")
    fig.set_size_inches(10, 2.5 * len(sensors) + 0.5)
    return PlotFile(_save(fig, path), tuple(titles))




def plot_time_offset(report: dict[str, Any], path: Path, truth_ms: float | None = None) -> PlotFile:
    """The online camera-IMU time offset (ms) against time with its ±3σ band (``report.json``
    ``vision.time_offset_history``); ``truth_ms`` drawn when known."""
    h = report["vision"]["time_offset_history"]
    t_s = np.asarray(h["t_s"], float)
    t_s = t_s - t_s[0]
    v, s = np.asarray(h["value_ms"], float), np.asarray(h["std_ms"], float)
    fig = Figure(figsize=(10, 4))
    ax = fig.subplots()
    ax.fill_between(t_s, v - 3 * s, v + 3 * s, color="tab:blue", alpha=0.2, label="±3 sigma")
    ax.plot(t_s, v, color="tab:blue", lw=1.0, label="estimate")
    if truth_ms is not None:
        ax.axhline(truth_ms, color="tab:green", lw=1.0, label=f"truth {truth_ms:g} ms")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("timeshift_cam_imu [ms]")
    title = f"camera-IMU time offset: {v[-1]:.2f} ± {s[-1]:.2f} ms at the end"
    ax.set_title(title)
    ax.legend(loc="upper right")
    return PlotFile(_save(fig, path), (title,))


def _true_offset_ms(dataset: Dataset | None) -> float | None:
    """The simulator's injected camera-IMU offset (ms) from its ``scenario.yaml`` (None: not
    a simulation)."""
    if dataset is None:
        return None
    import yaml

    path = (Path(dataset.root) / "mav0" / "state_groundtruth_estimate0" / "scenario.yaml")
    if not path.is_file():
        return None
    cam = (yaml.safe_load(path.read_text()) or {}).get("camera") or {}
    return float(cam.get("timeshift_cam_imu", 0.0)) * 1e3


def plot_run(run_dir: Path | str, dataset: Dataset | None, out_dir: Path | str) -> list[PlotFile]:
    """Write the three figures of a run into ``out_dir``; the error and NEES figures need
    ``dataset`` with ground truth."""
    rec = read_run(run_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    made_on = rec.report.get("dataset")
    if dataset is not None and made_on is not None and made_on != dataset.name:
        log.warning("%s was made on the data set '%s', and %s is '%s': the errors are against "
                    "another recording's ground truth unless it is the same one renamed",
                    run_dir, made_on, dataset.root, dataset.name)  # fmt: skip
    if dataset is not None and dataset.groundtruth is not None:
        g = np.asarray(dataset.gravity_W, float)
        up = -g / np.linalg.norm(g)
        err = run_errors(rec, dataset.groundtruth, up)
        sm = None
        if (Path(run_dir) / "states_smoothed.csv").is_file():
            sm = run_errors(read_run(run_dir, smoothed=True), dataset.groundtruth, up)
        files.append(plot_errors(err, out / "errors.png", sm))
        if np.isfinite(err.nees).any():
            files.append(plot_nees(err, out / "nees.png", smoothed=sm))
    elif dataset is not None:  # the measurements' figure needs none
        log.warning("%s: no ground truth, so no error or NEES plots", dataset.root)
    files.append(plot_measurements(rec, out / "measurements.png"))
    if "time_offset_history" in (rec.report.get("vision") or {}):
        files.append(plot_time_offset(rec.report, out / "time_offset.png",
                                      _true_offset_ms(dataset)))  # fmt: skip
    return files
