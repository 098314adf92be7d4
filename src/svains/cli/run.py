"""``svains run DATASET --method ins|vo|lc|tc|3d --out DIR``: run one navigation method."""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from svains.cli._common import (
    ROTATION_HELP,
    GpsOutageOption,
    GpsUntilOption,
    SonarOption,
    TopicOption,
    check_out_dir,
    fail,
    non_negative_finite,
    positive_finite,
    rotation_choice,
)
from svains.errors import SvainsError

# An ATE fit that tilts the estimate more than this (deg) is said in the run table.
ATE_TILT_NOTE_DEG = 1.0
# the share of a run in vision gaps from which its end says so
MOSTLY_BLIND = 0.5

_SHOWN = ("ate_rmse_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean",
          "wall_s", "realtime_factor", "wall_end_to_end_s",
          "realtime_factor_end_to_end")  # fmt: skip


def run(
    dataset: Annotated[Path, typer.Argument(help="Data set: ASL/EuRoC, TUM-VI or KITTI folder, "
                                                 "or a ROS bag (.bag, .db3, .mcap).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("run_out"),
    config_file: Annotated[
        Path | None,
        typer.Option("--config", help="Run configuration YAML (e.g. a previous OUT/config.yaml)."),
    ] = None,
    method: Annotated[
        str | None, typer.Option("--method", help="ins, tc, 3d, lc or vo (default: ins).")
    ] = None,
    model: Annotated[
        str | None,
        typer.Option("--model", help="paper (eq. 14 state) or biased (+ IMU biases; the default)."),
    ] = None,
    init: Annotated[
        str | None, typer.Option("--init", help="static (the default), gps (in flight), vision (in "
                                 "flight from stereo and IMU) or groundtruth.")
    ] = None,
    gps: Annotated[bool | None, typer.Option("--gps/--no-gps", help="Fuse GPS.")] = None,
    mag: Annotated[bool | None, typer.Option("--mag/--no-mag", help="Fuse magnetometer.")] = None,
    sonar: SonarOption = None,
    start: Annotated[
        float | None,
        typer.Option("--start", help="Skip the first S seconds of the data.",
                     callback=non_negative_finite),
    ] = None,
    duration: Annotated[
        float | None,
        typer.Option("--duration", help="Stop S seconds after the start.",
                     callback=positive_finite),
    ] = None,
    gps_outage: GpsOutageOption = None,
    gps_until: GpsUntilOption = None,
    features: Annotated[
        bool | None,
        typer.Option(
            "--features/--images",
            help="Vision tracks from features0 or from images (default: features0 if present).",
        ),
    ] = None,
    rotation: Annotated[
        str | None,
        typer.Option("--rotation", help=ROTATION_HELP, callback=rotation_choice),
    ] = None,
    setting: Annotated[
        list[str] | None,
        typer.Option("--set", help="Any option section.key=value (e.g. vision.frame_stride=4, "
                     "filter.max_predict_steps=10); repeatable."),
    ] = None,
    synthetic_features: Annotated[
        float | None,
        typer.Option(
            "--synthetic-features",
            help="Simulate features0 at this rate [Hz] along the ground truth.",
            callback=positive_finite,
        ),
    ] = None,
    calib: Annotated[
        Path | None,
        typer.Option("--calib", help="Kalibr camchain-imucam.yaml replacing the data set's "
                     "camera calibration (config key replay.calib)."),
    ] = None,
    imu_calib: Annotated[
        Path | None,
        typer.Option("--imu-calib", help="Kalibr imu.yaml replacing the data set's IMU noise "
                     "(config key replay.imu_calib)."),
    ] = None,
    topic: TopicOption = None,
    smooth: Annotated[
        bool | None,
        typer.Option("--smooth/--no-smooth", help="Also smooth the run forward-backward (RTS) "
                     "and write the *_smoothed files (config key smoother.enabled)."),
    ] = None,
    rerun: Annotated[
        Path | None,
        typer.Option("--rerun", help="After the run, save a rerun recording (.rrd; needs "
                     "svains\\[viz])."),
    ] = None,
    rerun_spawn: Annotated[
        bool, typer.Option("--rerun-spawn", help="After the run, open the rerun viewer.")
    ] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Write over a non-empty --out: its outputs "
                           "replaced at the end, only if the run finished; other files kept.")
    ] = False,
    allow_degraded: Annotated[
        bool,
        typer.Option("--allow-degraded",
                     help="Exit 0 even when a vision method fused no vision at all."),
    ] = False,
) -> None:
    """Run METHOD over DATASET; write trajectory.tum, trajectory_euroc.csv, pose_covariance.csv,
    states.csv, updates.csv, tracks.csv (vision), report.json and the effective config.yaml into
    OUT (with --smooth also trajectory_smoothed.tum, trajectory_smoothed_euroc.csv,
    pose_covariance_smoothed.csv and states_smoothed.csv; camchain_estimated.yaml where the
    camera's extrinsics or time offset were estimated); with --rerun/--rerun-spawn, then a
    rerun recording of the run."""
    from svains.cli.run_config import (
        build_config,
        effective_config_text,
        filter_only_settings,
        gps_off_switches,
        kalibr_switches,
        topic_switches,
    )
    from svains.datasets import load_dataset
    from svains.datasets.rosbag import parse_topic_roles
    from svains.evaluation.compare import degraded_note
    from svains.evaluation.run import run_method
    from svains.replay import resolve_config

    started_s = time.perf_counter()
    check_out_dir(out, force, inputs=[dataset])
    console = Console()
    for name, value, known in (("--model", model, ("paper", "biased")),
                               ("--method", method, ("ins", "vo", "lc", "tc", "3d")),
                               ("--init", init, ("static", "gps", "groundtruth", "vision"))):
        if value is not None and value not in known:
            raise typer.BadParameter(f"{name} must be {', '.join(known[:-1])} or {known[-1]}, "
                                     f"got {value!r}")
    try:
        switches = {
            "method": method, "model": model, "init.mode": init, "use_gps": gps,
            "use_mag": mag, "use_sonar": sonar, "duration_s": duration, "replay.start_s": start,
            "vision.rotation": rotation, "smoother.enabled": smooth,
            "vision.source": {None: None, True: "features", False: "images"}[features],
            **gps_off_switches(gps_outage, gps_until),
            "replay.synthetic_features_hz": synthetic_features,
            **kalibr_switches(calib, imu_calib), **topic_switches(topic),
        }  # fmt: skip
        config = build_config(config_file, setting, switches)
        if config.method == "vo" and config.smoother.enabled:  # it was ignored, files missing
            raise typer.BadParameter("--smooth (smoother.enabled): vo has no filter to smooth; "
                                     "ins, lc, tc and 3d do")  # fmt: skip
        unused = filter_only_settings(setting) if config.method == "vo" else []
        if unused:  # set in vain, without a word (a user's probe: --set zupt.after_start=true)
            logging.getLogger(__name__).warning("vo has no filter: %s not used",
                                                ", ".join(unused))
        ds = load_dataset(dataset, calib=config.replay.calib, imu_calib=config.replay.imu_calib,
                          topics=parse_topic_roles(config.replay.topics))
        hz = config.replay.synthetic_features_hz
        if hz is not None:
            from svains.replay.synthetic import with_synthetic_features

            ds = with_synthetic_features(ds, rate_hz=hz)
            console.print(f"simulated features0 at {hz:g} Hz along the ground truth")
        config = resolve_config(ds, config)
        label = f"{config.method} ({config.model})"
        with Progress(
            TextColumn(label), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
            TimeElapsedColumn(), console=console, transient=True,
        ) as bar:  # fmt: skip
            task = bar.add_task("run", total=1.0)
            result = run_method(
                ds, None, config, out_dir=out, progress=lambda f: bar.update(task, completed=f),
                config_text=effective_config_text(config, dataset), started_s=started_s,
            )
        if rerun is not None or rerun_spawn:
            from svains.evaluation.viewer import write_recording

            write_recording(out, ds, rerun, spawn=rerun_spawn)
    except SvainsError as exc:
        fail(exc)
    rep = result.report
    sm = rep.get("smoothed")
    table = Table(title=f"{rep['method']} on {rep.get('dataset', dataset)}")
    table.add_column("figure")
    table.add_column("value" if sm is None else "forward", justify="right")
    if sm is not None:
        table.add_column("smoothed", justify="right")

    def row(name: str, *values: str) -> None:
        table.add_row(name, *values[: 1 if sm is None else 2])

    def fmt(v: object) -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"

    def blocks(r: dict) -> str:
        # Each block against its own marginal covariance; consistent: 3/3/2/1.
        b = r.get("nees_blocks") or {}
        keys = ("position", "velocity", "roll_pitch", "yaw")
        return "/".join(f"{b[k]:.3g}" for k in keys) if b else "-"

    for key in _SHOWN:
        # The smoothed column's wall_s is the backward pass's; it has no real-time factor.
        other = None if key.startswith(("realtime_factor", "wall_end")) else (sm or {}).get(key)
        row(key, fmt(rep.get(key)), fmt(other))
        if key == "nees_mean" and rep.get("nees_blocks"):
            row("nees_blocks p/v/rp/yaw", blocks(rep), blocks(sm or {}))
        if key == "nees_mean" and rep.get("nees_start_anchored") is not None:
            # The frame the start defines, not the fit over the run (see docs/conventions.md).
            row("nees in the start's frame", fmt(rep["nees_start_anchored"]),
                fmt((sm or {}).get("nees_start_anchored")))
    if rep.get("alignment") is not None:
        # The ATE row's fit; one that tilts a gravity-aligned run trades its tilt for position
        # error, and `svains evaluate --align posyaw` gives the figure without it (a probe).
        tilt = rep.get("ate_fit_tilt_deg")
        said = str(rep["alignment"]) + (
            f" (the fit tilted the estimate {tilt:.2f}°; posyaw: `svains evaluate --align "
            "posyaw`)" if tilt is not None and tilt > ATE_TILT_NOTE_DEG
            and rep.get("method") != "vo" else "")  # (vo's own tilt is its drift)
        row("ATE alignment", said, "")
    if rep.get("reference_tilt_deg") is not None:
        # The reference frame's tilt from gravity, removed before the errors and the NEES.
        row("reference tilt removed [deg]", f"{rep['reference_tilt_deg']:.3f}", "")
    if rep.get("errors_alignment") is not None:
        # Which degrees of freedom were aligned before the RMSE/NEES rows (none: raw errors).
        row("errors alignment", str(rep["errors_alignment"]), "")
    if (rep.get("init") or {}).get("heading_source"):
        row("heading from the GPS", heading_found(rep["init"]), "")
    later = later_turns(rep)
    if later:
        row("heading turned later (GPS velocities)", later, "")
    for name, c in rep.get("measurements", {}).items():
        row(f"{name} fused/rejected", f"{c['fused']}/{c['rejected']}", "")
    for name, v in rep.get("vision", {}).items():
        if name != "time_offset_history":  # per frame: report.json and time_offset.png
            row(f"vision {name}", _brief(v), "")
    if rep.get("vision_gaps"):
        row("vision gaps", f"{len(rep['vision_gaps'])}, {100 * rep['vision_gap_fraction']:.0f} % "
            f"of the run, longest {rep['vision_longest_gap_s']:.1f} s", "")
    if rep.get("outage_max_error_m"):
        row("outage max error [m]", ", ".join(f"{e:.2f}" for e in rep["outage_max_error_m"]),
            ", ".join(f"{e:.2f}" for e in (sm or {}).get("outage_max_error_m") or []))
    if sm is not None:
        per_hour = sm["history_mb_per_hour"]
        row("history kept [MB]", "-", f"{sm['history_mb']:.3g}" + (
            "" if per_hour is None else f" ({per_hour:.3g} per hour of data)"))
        if sm.get("chain_cuts"):
            row("smoother chain cuts", "-", f"{sm['chain_cuts']} (the smoothing does not "
                "reach across a reset of the state)")
    console.print(table)
    # the files this run wrote (``vo`` writes no covariance: a user's probe read
    # "pose_covariance.csv" here where there was none)
    names = [n for n in ("trajectory_euroc.csv", "pose_covariance.csv", "states.csv",
                         "updates.csv", "tracks.csv", "trajectory_smoothed.tum",
                         "trajectory_smoothed_euroc.csv", "pose_covariance_smoothed.csv",
                         "states_smoothed.csv", "camchain_estimated.yaml")
             if (out / n).is_file()]  # fmt: skip
    # one line whatever the width (a log grepped for a path must find it whole)
    console.print(escape(f"wrote {out}/trajectory.tum, {', '.join(names)}, report.json, "
                         "config.yaml"), soft_wrap=True)
    if rerun is not None:
        console.print(f"wrote {rerun} (open with: rerun {rerun})")
    note = degraded_note(rep) if rep.get("method") == "vo" else None
    if note is not None:  # exit 0 with an empty or broken trajectory before
        fail(f"vo estimated {note} (svains info and svains frontend show what the images "
             "give)")
    if not rep.get("vision_degraded") and rep.get("vision_gap_fraction", 0.0) >= MOSTLY_BLIND:
        # a run fused a few frames and rode the IMU for the rest: said under the table, where
        # the figures are read (a probe: 90 % of a run without vision, and no word at its end)
        console.print(f"[yellow]warning:[/yellow] {rep['method']} went without vision for "
                      f"{100 * rep['vision_gap_fraction']:.0f} % of the run (report.json "
                      "vision_gaps): its figures are mostly the IMU's")  # fmt: skip
    if rep.get("vision_degraded") and not allow_degraded:
        # Never silently degraded: the outputs are written, but the run is not what was asked.
        fail(f"{rep['method']} fused no vision update: the run is plain INS (see report.json "
             "vision_gaps; --allow-degraded accepts it)")


def heading_found(init: dict) -> str:
    """A start held in a local frame until the GPS gave its heading (``report.json``'s
    ``init``): the turn, when and from what, and the fixes held meanwhile and fused at the
    turn (said only with ``-v`` before: a user's probe)."""
    # "turned": the change applied, not a heading; the time from the filter's start, which
    # may come after --start (a probe read both otherwise)
    line = (f"turned {init['heading_turn_deg']:+.1f}° ± {init['heading_std_deg']:.1f}° "
            f"{init['heading_found_s']:.1f} s after the start, from "
            f"{init['heading_source']}")  # fmt: skip
    held = init.get("gps_fixes_held")
    if held:
        line += f"; {held} fix(es) held"
    if "held_fixes_fused" in init:
        line += f", {init['held_fixes_fused']} fused at the turn"
    return line


def later_turns(rep: dict) -> str:
    """The heading check's turns after any that ended a start's heading wait (``report.json``'s
    ``heading_check``), "" without: a probe read only the wait's, wrong, turn in the table
    though the check turned the state back 8 s later."""
    turns = [t for t in (rep.get("heading_check") or {}).get("turns") or []
             if not t.get("wait")]  # fmt: skip
    return ", ".join(f"{t['angle_deg']:+.1f}° ± {t['std_deg']:.1f}°"
                     + (" (camera)" if t.get("witness") == "camera" else "") for t in turns)


def _brief(v: object) -> str:
    """A report value for the table: a check's dict as ``key value`` pairs, numbers to 4
    significant digits, flags only when set, nested detail left to report.json (a repr of
    the dict wrapped over 30 lines before)."""
    if not isinstance(v, dict):
        return f"{v:.4g}" if isinstance(v, float) else str(v)
    parts = []
    for k, x in v.items():
        if isinstance(x, bool):
            parts += [k] if x else []
        elif isinstance(x, int | float | str):
            parts.append(f"{k} {x:.4g}" if isinstance(x, float) else f"{k} {x}")
    return ", ".join(parts) if parts else "-"


def register(app: typer.Typer) -> None:
    app.command("run")(run)
