"""A campaign's figures (PNG, matplotlib object API: no pyplot state, safe on any thread):
a box plot per metric with one box per method (and config and source when there are several),
and the average NEES per time step against its 95 % bounds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from svains.batch.consistency import NeesTest
from svains.batch.summary import GroupKey, metric_values


def _label(key: GroupKey, show_source: bool, show_config: bool) -> str:
    source, config, method = key
    parts = [method] + ([config] if show_config else []) + ([source] if show_source else [])
    return "\n".join(parts)


def boxplot_metric(
    groups: dict[GroupKey, list[dict[str, Any]]], key: str, path: Path
) -> bool:
    """Box plot of ``key`` per (source, config, method) group into ``path``; False (nothing
    written) when no group has a value."""
    data = {g: metric_values(rows, key) for g, rows in groups.items()}
    data = {g: v for g, v in data.items() if v.size}
    if not data:
        return False
    show_source = len({g[0] for g in data}) > 1
    show_config = len({g[1] for g in data}) > 1
    fig = Figure(figsize=(max(4.0, 0.9 * len(data) + 1.5), 3.6), layout="constrained")
    ax = fig.add_subplot()
    ax.boxplot(list(data.values()), showmeans=True)
    ax.set_xticks(range(1, len(data) + 1),
                  [_label(g, show_source, show_config) for g in data])  # fmt: skip
    ax.set_ylabel(key)
    ax.set_title(f"{key} over {max(v.size for v in data.values())} runs per box")
    ax.grid(True, axis="y", alpha=0.3)
    fig.savefig(path, dpi=110)
    return True


def nees_figure(key: GroupKey, test: NeesTest, path: Path) -> None:
    """Average NEES per step against time, with its per-step 95 % bounds."""
    fig = Figure(figsize=(7.0, 3.4), layout="constrained")
    ax = fig.add_subplot()
    t_s = (test.t_ns - test.t_ns[0]) * 1e-9
    ax.plot(t_s, test.nees_avg, lw=1.0, label=f"average NEES, N = {test.n_runs}")
    for b, name in zip(test.bounds, ("95 % bounds", None), strict=True):
        ax.axhline(b, color="k", ls="--", lw=0.8, label=name)
    ax.set_yscale("log" if np.nanmax(test.nees_avg) > 10 * test.bounds[1] else "linear")
    ax.set_xlabel("time since the first state [s]")
    ax.set_ylabel("NEES (9 dof)")
    ax.set_title(f"{' / '.join(key)}: {100 * test.fraction_inside:.0f} % of steps inside")
    ax.legend(loc="best")
    ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
