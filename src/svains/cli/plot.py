"""``svains plot RUN_DIR --dataset D``: errors with ±3σ, NEES, fused/rejected, time offset."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from svains.cli._common import check_out_file, fail, usage_error
from svains.errors import SvainsError


def plot(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of svains run.")],
    dataset: Annotated[
        Path | None,
        typer.Option("--dataset", help="The run's data set (ground truth for errors and NEES)."),
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="Where to write the PNGs (default RUN_DIR).")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace existing PNGs.")] = False,
) -> None:
    """Write errors.png, nees.png and measurements.png for a run (and time_offset.png when the
    run estimated the camera-IMU time offset)."""
    from svains.datasets import load_dataset
    from svains.evaluation.plots import plot_run
    from svains.evaluation.run_record import PLOT_NAMES, replay_sources

    if run_dir.is_file():
        usage_error(f"{run_dir} is a file: give the run's folder ({run_dir.parent})", "RUN_DIR")
    for name in PLOT_NAMES:  # before any work: never replace a file without --force
        check_out_file((out if out is not None else run_dir) / name, force, "--out")

    try:
        # the Kalibr files and topics the run read it with (a folder calibrated by a
        # camchain alone: a user's probe)
        ds = load_dataset(dataset, **replay_sources(run_dir)) if dataset is not None else None
        files = plot_run(run_dir, ds, out if out is not None else run_dir)
    except SvainsError as exc:
        fail(exc)
    console = Console()
    for f in files:
        console.print(escape(f"wrote {f.path}: {'; '.join(f.panels[:3])}"
                             + (" ..." if len(f.panels) > 3 else "")))  # fmt: skip
    if dataset is None:
        console.print("no --dataset: errors.png and nees.png need its ground truth")
    elif ds is not None and ds.groundtruth is None:
        console.print(escape(f"{dataset} has no ground truth: errors.png and nees.png need it"))


def register(app: typer.Typer) -> None:
    app.command("plot")(plot)
