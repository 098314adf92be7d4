"""``svains run DATASET --method ins|vo|lc|tc|3d --out DIR``: run one navigation method."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from svains.cli._common import check_out_dir, fail, positive_finite
from svains.cli.compare import parse_settings
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
    init: Annotated[
        str, typer.Option("--init", help="static, gps (in flight) or groundtruth.")
    ] = "static",
    gps: Annotated[bool, typer.Option("--gps/--no-gps", help="Fuse GPS when present.")] = True,
    mag: Annotated[bool, typer.Option("--mag/--no-mag", help="Fuse magnetometer.")] = True,
    sonar: Annotated[bool, typer.Option("--sonar/--no-sonar", help="Fuse sonar.")] = True,
    duration: Annotated[
        float | None,
        typer.Option(
            "--duration", help="Process only this many seconds.", callback=positive_finite
        ),
    ] = None,
    features: Annotated[
        bool | None,
        typer.Option(
            "--features/--images",
            help="Vision tracks from features0 or from images (default: features0 if present).",
        ),
    ] = None,
    rotation: Annotated[
        str,
        typer.Option("--rotation", help="Vision motion model: linear (paper eq. 18), exp or imu."),
    ] = "imu",
    setting: Annotated[
        list[str] | None,
        typer.Option("--set", help="Vision option key=value (e.g. frame_stride=4); repeatable."),
    ] = None,
    synthetic_features: Annotated[
        float | None,
        typer.Option(
            "--synthetic-features",
            help="Simulate features0 at this rate [Hz] along the ground truth.",
            callback=positive_finite,
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Write into a non-empty --out (replacing files).")
    ] = False,
) -> None:
    """Run METHOD over DATASET; write trajectory.tum, states.csv and report.json into OUT."""
    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.vision import tune_run_options

    check_out_dir(out, force)
    console = Console()
    if model not in ("paper", "biased"):
        raise typer.BadParameter(f"--model must be paper or biased, got {model!r}")
    if method not in ("ins", "vo", "lc", "tc", "3d"):
        raise typer.BadParameter(f"--method must be ins, vo, lc, tc or 3d, got {method!r}")
    if init not in ("static", "gps", "groundtruth"):
        raise typer.BadParameter(f"--init must be static, gps or groundtruth, got {init!r}")
    try:
        source = {None: "auto", True: "features", False: "images"}[features]
        settings = {"rotation": rotation, **parse_settings(setting)}
        options = build_run_options(model, init, gps, mag, sonar, duration, source, settings)
        ds = load_dataset(dataset)
        if synthetic_features is not None:
            from svains.navigation.vision_synthetic import with_synthetic_features

            ds = with_synthetic_features(ds, rate_hz=synthetic_features)
            console.print(
                f"simulated features0 at {synthetic_features:g} Hz along the ground truth"
            )
        # Same per-method noise treatment as ``svains compare`` (vision methods only).
        options = tune_run_options(ds, method, options)
        with Progress(
            TextColumn(f"{method} ({model})"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
            TimeElapsedColumn(), console=console, transient=True,
        ) as bar:  # fmt: skip
            task = bar.add_task("run", total=1.0)
            result = run_method(
                ds, method, options, out_dir=out, progress=lambda f: bar.update(task, completed=f)
            )
    except SvainsError as exc:
        fail(exc)
    rep = result.report
    table = Table(title=f"{rep['method']} on {rep.get('dataset', dataset)}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key in _SHOWN:
        v = rep.get(key)
        table.add_row(
            key, "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"
        )
    if rep.get("errors_alignment") is not None:
        # Which degrees of freedom were aligned before the RMSE/NEES rows (none: raw errors).
        table.add_row("errors alignment", str(rep["errors_alignment"]))
    for name, c in rep.get("measurements", {}).items():
        table.add_row(f"{name} fused/rejected", f"{c['fused']}/{c['rejected']}")
    for name, v in rep.get("vision", {}).items():
        table.add_row(f"vision {name}", str(v))
    if rep.get("outage_max_error_m"):
        table.add_row(
            "outage max error [m]", ", ".join(f"{e:.2f}" for e in rep["outage_max_error_m"])
        )
    console.print(table)
    console.print(f"wrote {out}/trajectory.tum, states.csv, report.json")


def build_run_options(
    model: str,
    init: str,
    gps: bool,
    mag: bool,
    sonar: bool,
    duration: float | None,
    source: str,
    settings: dict[str, Any],
) -> Any:
    """``RunOptions`` from ``svains run``'s switches; ``settings`` = vision ``--set`` options
    (validated here, so a bad key fails before any data is loaded)."""
    from svains.navigation.options import InitOptions, RunOptions
    from svains.navigation.vision import VisionOptions

    method_options = {"source": source, **settings}
    VisionOptions.from_mapping(method_options)
    return RunOptions(
        model=model,  # type: ignore[arg-type]
        init=InitOptions(mode=init),  # type: ignore[arg-type]
        use_gps=gps,
        use_mag=mag,
        use_sonar=sonar,
        duration_s=duration,
        method_options=method_options,
    )


def register(app: typer.Typer) -> None:
    app.command("run")(run)
