"""``svains batch SPEC.yaml --out DIR``: a campaign on Dask (local cluster or ``--scheduler``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from svains.cli._common import fail, one_line, probe_writable
from svains.errors import SvainsError


def batch(
    spec: Annotated[Path, typer.Argument(help="Campaign spec (YAML).")],
    out: Annotated[Path, typer.Option("--out", help="Campaign folder (runs, summary).")],
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", envvar="DASK_SCHEDULER_ADDRESS",
                     help="Dask scheduler address (tcp://HOST:8786 or tls://...); default: a "
                     "local cluster on 127.0.0.1."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option("--workers", min=1, help="Local cluster: worker processes (default: cores)."),
    ] = None,
    sequential: Annotated[
        bool, typer.Option("--sequential", help="Run in this process, without Dask.")
    ] = False,
    figures: Annotated[bool, typer.Option("--figures/--no-figures", help="Write PNGs.")] = True,
) -> None:
    """Run every unfinished run of SPEC into OUT, then write OUT/summary.csv and summary.md."""
    from svains.batch import CampaignProgress, load_spec, run_campaign
    from svains.batch.summary import unknown_metrics

    console = Console()
    probe_writable(out, "--out")  # before any run: a campaign folder that cannot be written
    try:
        campaign = load_spec(spec)
        total = len(campaign.tasks())
        with Progress(
            TextColumn(escape(campaign.name)), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(), console=console,
        ) as bar:  # fmt: skip
            task = bar.add_task("runs", total=total, failed=0)

            def show(p: CampaignProgress) -> None:
                bar.update(task, completed=p.skipped + p.done, failed=p.failed)
                if p.last.error is not None:
                    bar.console.print(f"[red]failed[/red] {escape(p.last.task_id)}: "
                                      f"{escape(one_line(p.last.error))}", soft_wrap=True)

            summary = run_campaign(
                campaign, out, scheduler=scheduler, n_workers=workers, sequential=sequential,
                progress=show, figures=figures,
            )
            bar.update(task, completed=total - summary.count("pending"))
    except SvainsError as exc:
        fail(exc)
    console.print(f"{summary.count('ok')} of {len(summary.rows)} runs finished, "
                  f"{summary.count('failed')} failed; wrote {escape(str(out))}/summary.csv, "
                  "summary.md")  # fmt: skip
    for (source, config, method), t in summary.nees.items():
        lo, hi = t.overall_bounds_runs
        name = escape(f"{source}/{config}/{method}")
        console.print(f"NEES {name}: {t.overall:.3f} over {t.n_runs} runs, "
                      f"95 % bounds [{lo:.3f}, {hi:.3f}]: {t.verdict}")  # fmt: skip
    for key, close in unknown_metrics(campaign.metrics, summary.rows).items():
        console.print(f"[yellow]warning:[/yellow] metric {escape(key)!r} is in no finished "
                      "run's report" + (f" (closest: {escape(', '.join(close))})" if close
                                        else ""))  # fmt: skip
    if summary.count("failed"):  # a script or CI must see that the campaign is not whole
        fail(f"{summary.count('failed')} of {len(summary.rows)} runs failed (their errors: "
             f"{out}/summary.md)")


def register(app: typer.Typer) -> None:
    app.command("batch")(batch)
