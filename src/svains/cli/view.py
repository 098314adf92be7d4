"""``svains view RUN_DIR --dataset D --out run.rrd``: a run as a rerun recording (needs the
``svains[viz]`` extra)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from svains.cli._common import check_out_file, fail
from svains.errors import SvainsError


def view(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of svains run.")],
    dataset: Annotated[
        Path | None,
        typer.Option("--dataset", help="The run's data set (ground truth and left images)."),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the recording here.")] = None,
    spawn: Annotated[
        bool, typer.Option("--spawn", help="Open the rerun viewer (needs a display).")
    ] = False,
    image_stride: Annotated[
        int, typer.Option("--image-stride", help="Log every N-th left image.")
    ] = 1,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --out file.")] = False,
) -> None:
    """Save a rerun recording of a run (.rrd), or show it live with --spawn."""
    from svains.datasets import load_dataset
    from svains.evaluation.run_record import replay_sources
    from svains.evaluation.viewer import write_recording

    if out is None and not spawn:
        raise typer.BadParameter("give --out x.rrd, --spawn, or both")
    check_out_file(out, force, "--out")
    try:
        # the Kalibr files and topics the run read it with (a folder calibrated by a
        # camchain alone: a user's probe)
        ds = load_dataset(dataset, **replay_sources(run_dir)) if dataset is not None else None
        path = write_recording(run_dir, ds, out, spawn=spawn, image_stride=image_stride)
    except SvainsError as exc:
        fail(exc)
    if path is not None:
        Console().print(escape(f"wrote {path} (open with: rerun {path})"))


def register(app: typer.Typer) -> None:
    app.command("view")(view)
