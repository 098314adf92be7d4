"""``svains run DATASET --method ins --out DIR``: run one navigation method over a data set."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from svains.errors import SvainsError

_SHOWN = ("ate_rmse_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean",
          "wall_s", "realtime_factor")  # fmt: skip


def run(
    dataset: Annotated[Path, typer.Argument(help="Data-set folder (ASL/EuRoC layout).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("run_out"),
    method: Annotated[str, typer.Option("--method", help="ins, tc, 3d, lc or vo.")] = "ins",
    model: Annotated[
        str, typer.Option("--model", help="paper (eq. 14 state) or biased (+ IMU biases).")
    ] = "biased",
    init: Annotated[str, typer.Option("--init", help="static or groundtruth.")] = "static",
    gps: Annotated[bool, typer.Option("--gps/--no-gps", help="Fuse GPS when present.")] = True,
    mag: Annotated[bool, typer.Option("--mag/--no-mag", help="Fuse magnetometer.")] = True,
    sonar: Annotated[bool, typer.Option("--sonar/--no-sonar", help="Fuse sonar.")] = True,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Process only this many seconds.")
    ] = None,
) -> None:
    """Run METHOD over DATASET; write trajectory.tum, states.csv and report.json into OUT."""
    from svains.datasets import load_dataset
    from svains.navigation.options import InitOptions, RunOptions
    from svains.navigation.runner import run_method

    console = Console()
    if model not in ("paper", "biased"):
        raise typer.BadParameter(f"--model must be paper or biased, got {model!r}")
    if init not in ("static", "groundtruth"):
        raise typer.BadParameter(f"--init must be static or groundtruth, got {init!r}")
    options = RunOptions(
        model=model,  # type: ignore[arg-type]
        init=InitOptions(mode=init),  # type: ignore[arg-type]
        use_gps=gps,
        use_mag=mag,
        use_sonar=sonar,
        duration_s=duration,
    )
    try:
        ds = load_dataset(dataset)
        with Progress(
            TextColumn(f"{method} ({model})"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
            TimeElapsedColumn(), console=console, transient=True,
        ) as bar:  # fmt: skip
            task = bar.add_task("run", total=1.0)
            result = run_method(
                ds, method, options, out_dir=out, progress=lambda f: bar.update(task, completed=f)
            )
    except SvainsError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(code=1) from exc
    rep = result.report
    table = Table(title=f"{rep['method']} on {rep.get('dataset', dataset)}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key in _SHOWN:
        v = rep.get(key)
        table.add_row(
            key, "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"
        )
    for name, c in rep.get("measurements", {}).items():
        table.add_row(f"{name} fused/rejected", f"{c['fused']}/{c['rejected']}")
    console.print(table)
    console.print(f"wrote {out}/trajectory.tum, states.csv, report.json")


def register(app: typer.Typer) -> None:
    app.command("run")(run)
