"""``svains frontend DATASET --out DIR``: run the stereo front end alone and report."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from svains.cli._common import TopicOption, check_out_dir, fail, one_of, usage_error
from svains.errors import ConfigError, DatasetError, SvainsError


def _frontend(
    dataset: Annotated[Path, typer.Argument(help="Data set folder (ASL/EuRoC or KITTI).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    figures: Annotated[bool, typer.Option("--figures", help="Write paper fig. 8 (PNG).")] = False,
    dense: Annotated[bool, typer.Option("--dense", help="Dense disparity instead of KLT.")] = False,
    bundle: Annotated[
        bool, typer.Option("--bundle/--no-bundle", help="Refine each egomotion by the two-frame "
                           "bundle adjustment (vo's default); --no-bundle: RANSAC's alone.")
    ] = True,
    dense_method: Annotated[
        str, typer.Option("--dense-method", help="sgbm or elas (needs pyelas).",
                         callback=one_of("sgbm", "elas"))
    ] = "sgbm",
    figure_frame: Annotated[
        int, typer.Option("--figure-frame", help="Frame index of fig. 8 (-1: middle).")
    ] = -1,
    force: Annotated[
        bool, typer.Option("--force", help="Write over a non-empty --out: its outputs "
                           "replaced at the end, only if the run finished; other files kept.")
    ] = False,
    calib: Annotated[
        Path | None, typer.Option("--calib", help="Kalibr camchain-imucam.yaml (the cameras' "
                                  "calibration, for a bag or instead of the data set's).")
    ] = None,
    topic: TopicOption = None,
) -> None:
    """Track features, match stereo, estimate egomotion per frame; write frames.csv, report.json."""
    from svains.cli.run_config import topic_roles
    from svains.datasets import load_dataset, stereo_pairs
    from svains.datasets.stereo_images import check_stereo_images
    from svains.frontend.pipeline import FrontendOptions
    from svains.frontend.run import frame_rows, run_frontend, summarize
    from svains.frontend.stereo import StereoMatchOptions
    from svains.outputs import atomic_write_text, replaced_dir

    if figure_frame < -1:
        usage_error(f"-1 (the middle frame) or a frame index, got {figure_frame}",
                    "--figure-frame")  # fmt: skip
    check_out_dir(out, force, inputs=[dataset])
    topics = topic_roles(topic)
    console = Console()
    try:
        ds = load_dataset(dataset, calib=calib, topics=topics)
        pairs = stereo_pairs(ds)
        if pairs[0].size < 2:
            raise DatasetError(
                f"{dataset}: {pairs[0].size} stereo pair(s) with images on disk; the front end "
                "needs at least 2 (cam0/cam1 images within the stereo tolerance)"
            )
        check_stereo_images(ds)
        opts = FrontendOptions(
            stereo=StereoMatchOptions(method=dense_method if dense else "sparse"), bundle=bundle
        )
        # Written in a staging folder that replaces OUT whole once the report is written.
        owned = ("frames.csv", "report.json", "figure8_features_depth.png").__contains__
        with replaced_dir(out, owned) as stage:
            n = int(pairs[0].size)
            pick = figure_frame if figure_frame >= 0 else n // 2
            if figures and not 1 <= pick < n:
                raise ConfigError(f"--figure-frame {figure_frame}: {ds.name} has {n} stereo "
                                  f"pairs; frames 1 to {n - 1} have tracks to draw")  # fmt: skip
            drawn: list[Path] = []

            def on_frame(i: int, tracks, fe) -> None:  # type: ignore[no-untyped-def]
                if figures and i == pick and tracks is not None and fe.last_rectified is not None:
                    from svains.evaluation.figure_frontend import figure_features_depth

                    drawn.append(figure_features_depth(
                        fe.last_rectified[0], tracks, fe.rig, stage / "figure8_features_depth.png",
                        title=f"{ds.name} frame {i}: {int(tracks.inlier.sum())} inliers, "
                        f"{int((~tracks.inlier).sum())} outliers (x)",
                    ))  # fmt: skip

            run = run_frontend(ds, pairs, opts, on_frame=on_frame)
            rows = frame_rows(run)
            text = io.StringIO(newline="")
            w = csv.DictWriter(text, fieldnames=list(rows[0].keys()) if rows else ["index"])
            w.writeheader()
            w.writerows(rows)
            atomic_write_text(stage / "frames.csv", text.getvalue())
            report = summarize(run)
            report["dataset"] = str(dataset)
            report["stereo_method"] = opts.stereo.method
            # report.json last: its presence says the output is complete
            atomic_write_text(stage / "report.json", json.dumps(report, indent=2) + "\n")
    except SvainsError as exc:
        fail(exc)
    console.print(json.dumps(report, indent=2))
    for p in drawn:
        console.print(f"figure: {out / p.name}")
    if figures and not drawn:
        typer.echo(f"warning: frame {pick} gave no tracks: figure 8 not drawn", err=True)


def register(app: typer.Typer) -> None:
    app.command("frontend")(_frontend)
