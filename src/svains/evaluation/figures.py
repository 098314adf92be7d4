"""The paper's comparison figures as PNG (matplotlib object API: no pyplot state).

- ``figure_estimates_errors`` (paper fig. 5): position and velocity estimates and errors against
  time for chosen methods, GPS outages shaded and GPS-loss instants marked;
- ``figure_method_trajectory`` (figs. 9-11): one method's trajectory against ground truth (after
  the run's alignment) and its x-velocity with error;
- ``figure_vo_breaks`` (fig. 7): the VO trajectory with the frames where tracking broke.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.evaluation.compare import align_to_groundtruth, gps_outages
from svains.navigation.outputs import RunResult
from svains.replay.groundtruth import interpolate_groundtruth

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)

_COLORS = {
    "ins": "tab:gray",
    "vo": "tab:purple",
    "lc": "tab:orange",
    "tc": "tab:blue",
    "3d": "tab:red",
}


def _truth(ds: Dataset, t_ns: NDArray[np.int64]) -> tuple[NDArray[np.bool_], F64, F64]:
    assert ds.groundtruth is not None
    inside, p, v, _ = interpolate_groundtruth(ds.groundtruth, t_ns)
    return inside, p, v


def _mark_outages(ax: Axes, outages: Sequence[tuple[int, int]], t0_ns: int) -> None:
    for i, (a, b) in enumerate(outages):
        ax.axvspan(
            (a - t0_ns) * 1e-9,
            (b - t0_ns) * 1e-9,
            color="k",
            alpha=0.08,
            label="GPS outage" if i == 0 else None,
        )
        ax.axvline((a - t0_ns) * 1e-9, color="k", lw=0.8, ls="--")


def figure_estimates_errors(
    ds: Dataset, results: dict[str, RunResult], methods: Sequence[str], path: Path
) -> Path | None:
    """Fig. 5: position/velocity norms of the estimate and errors vs time; None if no truth."""
    runs = {m: results[m] for m in methods if m in results and len(results[m].t_ns) > 1}
    if ds.groundtruth is None or not runs:
        return None
    t0 = int(ds.groundtruth.t_ns[0])
    outages = gps_outages(ds)
    fig = Figure(figsize=(12, 7))
    axes = fig.subplots(2, 2, sharex=True)
    tg = (ds.groundtruth.t_ns - t0) * 1e-9
    for j in range(3):
        axes[0, 0].plot(
            tg, ds.groundtruth.p_W_B[:, j], "k", lw=0.8, label="truth" if j == 0 else None
        )
        axes[1, 0].plot(tg, ds.groundtruth.v_W_B[:, j], "k", lw=0.8)
    for m, r in runs.items():
        inside, p, v = _truth(ds, r.t_ns)
        t = (r.t_ns[inside] - t0) * 1e-9
        c = _COLORS.get(m)
        for j in range(3):
            axes[0, 0].plot(
                t, r.x[inside, j], color=c, lw=0.8, ls=["-", "--", ":"][j], label=f"{m} {'xyz'[j]}"
            )
            axes[1, 0].plot(t, r.x[inside, 3 + j], color=c, lw=0.8, ls=["-", "--", ":"][j])
        axes[0, 1].plot(t, np.linalg.norm(r.x[inside, 0:3] - p, axis=1), color=c, label=m)
        axes[1, 1].plot(t, np.linalg.norm(r.x[inside, 3:6] - v, axis=1), color=c, label=m)
    for ax in axes.ravel():
        _mark_outages(ax, outages, t0)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("position [m]")
    axes[1, 0].set_ylabel("velocity [m/s]")
    axes[0, 1].set_ylabel("|position error| [m]")
    axes[1, 1].set_ylabel("|velocity error| [m/s]")
    axes[1, 0].set_xlabel("t [s]")
    axes[1, 1].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=6, ncol=3)
    axes[0, 1].legend(fontsize=8)
    fig.suptitle(f"{ds.name}: estimates and errors (GPS-loss instants dashed)")
    return _save(fig, path)


def _aligned(ds: Dataset, r: RunResult) -> tuple[F64, F64, NDArray[np.bool_]]:
    inside, p_gt, _ = _truth(ds, r.t_ns)
    res = align_to_groundtruth(r, ds, r.report.get("ate_alignment", "none"))
    p = res.p_est_aligned if res is not None else r.x[inside, 0:3]
    return p, p_gt, inside


def figure_method_trajectory(ds: Dataset, r: RunResult, method: str, path: Path) -> Path | None:
    """Figs. 9-11: trajectory vs ground truth (top view) and x-velocity with its error."""
    if ds.groundtruth is None or len(r.t_ns) < 3:
        return None
    p, p_gt, inside = _aligned(ds, r)
    _, _, v_gt = _truth(ds, r.t_ns)
    t = (r.t_ns[inside] - r.t_ns[0]) * 1e-9
    fig = Figure(figsize=(15, 4.5))
    axes = fig.subplots(1, 3)
    axes[0].plot(p_gt[:, 0], p_gt[:, 1], "k", lw=1, label="ground truth")
    axes[0].plot(
        p[:, 0],
        p[:, 1],
        color=_COLORS.get(method),
        lw=1,
        label=f"{method} ({r.report.get('ate_alignment', 'none')} aligned)",
    )
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, v_gt[:, 0], "k", lw=1, label="truth")
    axes[1].plot(t, r.x[inside, 3], color=_COLORS.get(method), lw=1, label=method)
    axes[1].set_ylabel("v_x [m/s]")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, r.x[inside, 3] - v_gt[:, 0], color=_COLORS.get(method), lw=1)
    if r.std.shape[0] == r.x.shape[0] and np.isfinite(r.std[inside, 3]).all():
        s = 3.0 * r.std[inside, 3]
        axes[2].fill_between(t, -s, s, color="k", alpha=0.1, label="±3 std")
        axes[2].legend(fontsize=8)
    axes[2].set_ylabel("v_x error [m/s]")
    for ax in axes[1:]:
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
    axes[0].grid(alpha=0.3)
    ate = r.report.get("ate_m")
    fig.suptitle(f"{ds.name}: {method}" + (f", ATE {ate:.3f} m" if ate is not None else ""))
    return _save(fig, path)


def figure_vo_breaks(ds: Dataset, r: RunResult, path: Path) -> Path | None:
    """Fig. 7: VO trajectory (top view) with the frames where tracking broke marked."""
    if len(r.t_ns) < 2:
        return None
    fig = Figure(figsize=(7, 6))
    ax = fig.subplots()
    if ds.groundtruth is not None:
        ax.plot(
            ds.groundtruth.p_W_B[:, 0], ds.groundtruth.p_W_B[:, 1], "k", lw=1, label="ground truth"
        )
    ax.plot(r.x[:, 0], r.x[:, 1], color=_COLORS["vo"], lw=1, label="VO")
    breaks = np.asarray(r.report.get("vo", {}).get("break_t_ns", []), np.int64)
    if breaks.size:
        idx = np.searchsorted(r.t_ns, breaks).clip(0, len(r.t_ns) - 1)
        ax.plot(r.x[idx, 0], r.x[idx, 1], "rx", ms=8, label=f"tracking breaks ({breaks.size})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{ds.name}: stereo VO alone")
    return _save(fig, path)


def comparison_figures(ds: Dataset, results: dict[str, RunResult], out_dir: Path) -> list[Path]:
    """All figures that the results allow, written into ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    out: list[Path | None] = []
    tight = [m for m in ("tc", "3d") if m in results]
    out.append(figure_estimates_errors(ds, results, tight or list(results), out_dir / "fig5.png"))
    for num, m in (("9", "lc"), ("10", "tc"), ("11", "3d")):
        if m in results:
            out.append(figure_method_trajectory(ds, results[m], m, out_dir / f"fig{num}_{m}.png"))
    if "vo" in results:
        out.append(figure_vo_breaks(ds, results["vo"], out_dir / "fig7_vo.png"))
    return [p for p in out if p is not None]


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path
