"""Campaigns: many runs (data sets or simulated scenarios x methods x seeds x settings) from a
YAML spec, on Dask, resumable, aggregated into tables, a Monte Carlo NEES test and figures.

Public API: :func:`load_spec` / :func:`parse_spec` -> :class:`CampaignSpec` (``tasks()``),
:func:`run_task` (one run), :func:`run_campaign` (all of them, then :func:`aggregate`).
"""

from svains.batch.aggregate import CampaignSummary, aggregate
from svains.batch.driver import CampaignProgress, run_campaign
from svains.batch.spec import CampaignSpec, Task, load_spec, parse_spec
from svains.batch.task import TaskResult, run_task

__all__ = [
    "CampaignProgress", "CampaignSpec", "CampaignSummary", "Task", "TaskResult", "aggregate",
    "load_spec", "parse_spec", "run_campaign", "run_task",
]  # fmt: skip
