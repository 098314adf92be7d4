"""Aggregate a campaign folder: ``summary.csv``, ``consistency.csv``, the figures, then
``summary.md`` (see :mod:`svains.batch.summary`). Reads only the runs' files, so it can be
re-run at any time, also on a campaign that is still going or that stopped half way."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from svains.batch.consistency import NeesTest
from svains.batch.figures import boxplot_metric, nees_figure
from svains.batch.spec import CampaignSpec
from svains.batch.summary import (
    GroupKey,
    group_rows,
    nees_tests,
    summary_markdown,
    summary_rows,
    write_consistency_csv,
    write_summary_csv,
)


@dataclass(frozen=True)
class CampaignSummary:
    """What :func:`aggregate` wrote: the rows of ``summary.csv`` and the NEES tests."""

    rows: list[dict[str, Any]]
    nees: dict[GroupKey, NeesTest]

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def aggregate(spec: CampaignSpec, out_dir: Path, figures: bool = True) -> CampaignSummary:
    """Write the campaign's tables (and figures) into ``out_dir`` from its runs' files."""
    out_dir = Path(out_dir)
    tasks = spec.tasks()
    rows = summary_rows(out_dir, tasks)
    write_summary_csv(out_dir / "summary.csv", rows)
    tests = nees_tests(out_dir, tasks, rows)
    if tests:
        write_consistency_csv(out_dir / "consistency.csv", tests)
    names: list[str] = []
    if figures:
        groups = group_rows(rows)
        for key in spec.metrics:
            name = f"box_{_slug(key)}.png"
            if boxplot_metric(groups, key, out_dir / name):
                names.append(name)
        for key, test in tests.items():
            name = f"nees_{_slug('_'.join(key))}.png"
            nees_figure(key, test, out_dir / name)
            names.append(name)
    (out_dir / "summary.md").write_text(summary_markdown(spec, rows, tests, names),
                                        encoding="utf-8")  # fmt: skip
    return CampaignSummary(rows, tests)
