"""``svains demo --out DIR``: simulate the paper's village flight, then compare every method."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from svains.cli._common import (
    ROTATION_HELP,
    check_out_dir,
    fail,
    positive_finite,
    rotation_choice,
    stereo_rate,
)
from svains.cli.compare import build_options, run_compare
from svains.errors import SvainsError


def demo(
    out: Annotated[Path, typer.Option("--out", help="Output folder (data set + comparison).")],
    seed: Annotated[int, typer.Option("--seed", help="Simulator seed.")] = 0,
    duration: Annotated[
        float, typer.Option("--duration", help="Flight length \\[s].", callback=positive_finite)
    ] = 110.0,
    camera_rate: Annotated[
        float, typer.Option("--camera-rate", help="Stereo rate [Hz], up to 20.",
                            callback=stereo_rate),
    ] = 2.0,
    images: Annotated[
        bool,
        typer.Option(
            "--images/--no-images",
            help="Render images and run the real stereo front end on them (default), or "
            "simulate feature tracks only (seconds, for quick looks).",
        ),
    ] = True,
    rotation: Annotated[
        str | None,
        typer.Option("--rotation", help=ROTATION_HELP, callback=rotation_choice),
    ] = None,
    methods: Annotated[
        str, typer.Option("--methods", help="Comma-separated methods.")
    ] = "ins,vo,lc,tc,3d",
    force: Annotated[
        bool, typer.Option("--force", help="Write into a non-empty --out (replacing files).")
    ] = False,
) -> None:
    """Village flight (IMU 100 Hz, GPS 1 Hz with four 10 s outages, magnetometer, sonar, stereo)
    simulated into OUT/dataset, then svains compare into OUT/compare."""
    from svains.sim import SimConfig, simulate

    check_out_dir(out, force, replaced_whole=False)
    console = Console()
    try:
        cfg = SimConfig()
        cfg = replace(cfg, seed=seed, duration_s=duration,
                      camera=replace(cfg.camera, rate_hz=camera_rate, render_images=images))
        t0 = time.perf_counter()
        root = simulate(cfg, out / "dataset", overwrite=force)
        console.print(f"simulated {duration:.0f} s village flight in "
                      f"{time.perf_counter() - t0:.1f} s -> {root}")
        # With images the tracks come from the real front end, not from the true features0.
        source = "images" if images else "features"
        opts = build_options("biased", "groundtruth", True, True, None, source,
                             [f"vision.rotation={rotation}"] if rotation else [])
        run_compare(root, out / "compare", [m.strip() for m in methods.split(",") if m.strip()],
                    opts, True, console)
    except SvainsError as exc:
        fail(exc)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
