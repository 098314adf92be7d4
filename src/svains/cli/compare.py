"""``svains compare DATASET --out DIR``: run every navigation method, write a table and figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import Progress

from svains.cli import _common
from svains.cli._common import one_line
from svains.errors import SvainsError


def build_options(
    model: str, init: str, gps: bool, mag: bool, duration: float | None, source: str,
    settings: list[str] | None, config_file: Path | None = None,
    calib: Path | None = None, imu_calib: Path | None = None, sonar: bool | None = None,
    gps_outages: list[str] | None = None, gps_until: float | None = None,
    topic: list[str] | None = None,
) -> Any:
    """``RunConfig`` from the command-line switches (``settings``: ``--set`` items; ``calib``,
    ``imu_calib``: Kalibr files, kept absolute in ``replay``; ``gps_outages``: START:DURATION
    texts)."""
    from svains.cli.run_config import (
        build_config,
        gps_off_switches,
        kalibr_switches,
        topic_switches,
    )

    switches = {"model": model, "init.mode": init, "use_gps": gps, "use_mag": mag,
                "use_sonar": sonar, "duration_s": duration, "vision.source": source,
                **gps_off_switches(gps_outages, gps_until),
                **kalibr_switches(calib, imu_calib), **topic_switches(topic)}  # fmt: skip
    return build_config(config_file, settings, switches)


def run_compare(
    dataset: Path, out: Path, methods: list[str], options: Any, figures: bool, console: Console,
    synthetic_features_hz: float | None = None, allow_degraded: bool = False,
) -> dict[str, Any]:
    """Load, run each method with a progress bar, write compare.json/.md and the figures."""
    from svains.cli.run_config import effective_config_text
    from svains.datasets.loader import load_dataset
    from svains.datasets.rosbag import parse_topic_roles
    from svains.evaluation.compare import (
        compare_owned,
        degraded_note,
        run_methods,
        write_comparison,
    )
    from svains.outputs import replaced_dir

    ds = load_dataset(dataset, calib=options.replay.calib, imu_calib=options.replay.imu_calib,
                      topics=parse_topic_roles(options.replay.topics))
    if synthetic_features_hz is not None:
        from svains.replay.synthetic import with_synthetic_features

        ds = with_synthetic_features(ds, rate_hz=synthetic_features_hz)
        console.print(f"simulated features0 at {synthetic_features_hz:g} Hz along the ground truth")
    # Built in a staging folder that replaces OUT whole at the end: an interrupted comparison
    # leaves the previous one untouched, never a mix of old and new method folders.
    with replaced_dir(out, compare_owned) as stage:
        with Progress(console=console, transient=True) as bar:
            tasks = {m: bar.add_task(m, total=1.0) for m in methods}
            results = run_methods(
                ds, methods, options, stage, lambda m, f: bar.update(tasks[m], completed=f),
                config_text=lambda c: effective_config_text(c, dataset),
            )
        reports = write_comparison(stage, results, f"svains compare: {ds.name}")
        figure_names = []
        if figures:
            from svains.evaluation.figures import comparison_figures

            figure_names = [p.name for p in comparison_figures(ds, results, stage)]
    for name in figure_names:
        console.print(f"figure: {out / name}")
    console.print((out / "compare.md").read_text(encoding="utf-8"), markup=False, soft_wrap=True)
    failed = [f"{m} ({one_line(r['error'])})" for m, r in reports.items()
              if isinstance(r, dict) and r.get("error")]  # fmt: skip
    degraded = [] if allow_degraded else [  # as svains run: vision asked for, none fused
        f"{m} ({note})" for m, r in reports.items()
        if isinstance(r, dict) and not r.get("error") and (note := degraded_note(r)) is not None]
    if failed or degraded:
        # The comparison of the others is written; the run as a whole did not succeed.
        _common.fail(f"{len(failed) + len(degraded)} of {len(reports)} method(s) failed: "
                     f"{'; '.join(failed + degraded)}"
                     + (" (--allow-degraded accepts them)" if degraded else ""))  # fmt: skip
    return reports


def compare(
    dataset: Annotated[Path, typer.Argument(help="Data set folder or ROS bag.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    methods: Annotated[
        str, typer.Option("--methods", help="Comma-separated methods: ins,vo,lc,tc,3d.")
    ] = "ins,vo,lc,tc,3d",
    features: Annotated[
        bool | None,
        typer.Option("--features/--images",
                     help="Tracks from features0 or from images (default: features0 if present)."),
    ] = None,
    model: Annotated[str, typer.Option("--model", help="State model: paper or biased.")] = "biased",
    rotation: Annotated[
        str | None,
        typer.Option("--rotation", help=_common.ROTATION_HELP, callback=_common.rotation_choice),
    ] = None,
    init: Annotated[
        str, typer.Option("--init", help="static, gps (in flight), vision (in flight "
                                 "from stereo and IMU) or groundtruth.")
    ] = "groundtruth",
    gps: Annotated[bool, typer.Option("--gps/--no-gps", help="Fuse GPS when present.")] = True,
    mag: Annotated[bool, typer.Option("--mag/--no-mag", help="Fuse magnetometer.")] = True,
    sonar: _common.SonarOption = None,
    gps_outage: _common.GpsOutageOption = None,
    gps_until: _common.GpsUntilOption = None,
    duration: Annotated[
        float | None,
        typer.Option("--duration", help="Use only the first S seconds.",
                     callback=_common.positive_finite),
    ] = None,
    figures: Annotated[bool, typer.Option("--figures/--no-figures", help="Write PNGs.")] = True,
    setting: Annotated[
        list[str] | None,
        typer.Option("--set", help="Any option section.key=value (e.g. vision.frame_stride=4); "
                     "repeatable."),
    ] = None,
    synthetic_features: Annotated[
        float | None,
        typer.Option("--synthetic-features",
                     help="Simulate features0 at this rate [Hz] along the ground truth.",
                     callback=_common.positive_finite),
    ] = None,
    calib: Annotated[
        Path | None, typer.Option("--calib", help="Kalibr camchain-imucam.yaml.")
    ] = None,
    imu_calib: Annotated[Path | None, typer.Option("--imu-calib", help="Kalibr imu.yaml.")] = None,
    topic: _common.TopicOption = None,
    smooth: Annotated[
        bool, typer.Option("--smooth", help="Also smooth each filter run forward-backward (RTS): "
                           "a 'smoothed' row per method and the *_smoothed files.")
    ] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Write over a non-empty --out: its outputs "
                           "replaced at the end, only if the comparison was written; other "
                           "files kept.")
    ] = False,
    allow_degraded: Annotated[
        bool, typer.Option("--allow-degraded", help="Exit 0 even when a vision method fused no "
                           "vision or vo linked no frames (their rows say so).")
    ] = False,
) -> None:
    """Run all methods on DATASET; write DIR/compare.md, DIR/compare.json and the figures."""
    from svains.evaluation.compare import METHODS

    names = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise typer.BadParameter(f"--methods: unknown {', '.join(map(repr, unknown))}; "
                                 f"known: {', '.join(METHODS)}")  # fmt: skip
    _common.check_out_dir(out, force, inputs=[dataset])
    try:
        source = {None: "auto", True: "features", False: "images"}[features]
        settings = [*([f"vision.rotation={rotation}"] if rotation else []),
                    *(["smoother.enabled=true"] if smooth else []), *(setting or [])]
        opts = build_options(model, init, gps, mag, duration, source, settings,
                             calib=calib, imu_calib=imu_calib, sonar=sonar,
                             gps_outages=gps_outage, gps_until=gps_until, topic=topic)
        run_compare(dataset, out, names, opts,
                    figures, Console(), synthetic_features, allow_degraded)
    except SvainsError as exc:
        _common.fail(exc)


def register(app: typer.Typer) -> None:
    app.command("compare")(compare)
