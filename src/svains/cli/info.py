"""``svains info DATASET``: streams, counts, rates, span, gaps, missing files, calibration."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from svains.cli._common import TopicOption, check_out_file, fail
from svains.errors import SvainsError


def _f(v: Any, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def _vec(v: Any) -> str:
    return "[" + ", ".join(f"{float(x):+.3f}" for x in v) + "]"


def _print(summary: dict[str, Any], console: Console) -> None:
    console.print(f"[bold]{summary['name']}[/bold]  ({summary['root']})")
    t = Table(title="Streams (times from the earliest sample)")
    for col in ("stream", "count", "rate [Hz] (median step)", "start [s]", "span [s]",
                "largest gap [s]", "gap at [s]"):  # fmt: skip
        t.add_column(escape(col), justify="left" if col == "stream" else "right")
    for s in summary["streams"].values():
        rate = _f(s["rate_hz"], ".2f")
        span, n = s["span_s"], s["count"]
        if s["rate_hz"] and span and n > 1 and abs((n - 1) / span / s["rate_hz"] - 1.0) > 0.05:
            # the median step's rate beside the mean's where samples are missing (KITTI raw's
            # IMU: 25 Hz by its median step, 16 Hz on average, 100 Hz declared: a probe)
            rate += f" ({(n - 1) / span:.2f} mean)"
        t.add_row(
            s["label"], str(s["count"]), rate, _f(s["start_s"], ".3f"),
            _f(s["span_s"], ".3f"), _f(s["largest_gap_s"], ".4f"), _f(s["largest_gap_at_s"], ".3f"),
        )  # fmt: skip
    console.print(t)
    missing = summary["missing_images"]
    if missing:
        detail = ", ".join(f"{k}: {v}" for k, v in missing.items())
        console.print(
            f"[yellow]Missing files:[/yellow] {sum(missing.values())} image(s) listed without "
            f"a file, skipped ({detail})"
        )
    else:
        console.print("Missing files: none")
    pairs = summary["stereo_pairs"]
    if pairs is not None and (pairs["cam0_unpaired"] or pairs["cam1_unpaired"]):
        console.print(
            f"[yellow]Stereo pairs:[/yellow] {pairs['pairs']}; without a partner: cam0 "
            f"{pairs['cam0_unpaired']}, cam1 {pairs['cam1_unpaired']} frame(s) (vision skips them)")
    unreadable = summary["unreadable_images"]
    if unreadable:
        n = sum(u["count"] for u in unreadable.values())
        detail = ", ".join(f"{k}: {u['count']}" for k, u in unreadable.items())
        first = next(iter(unreadable.values()))
        console.print(escape(
            f"Unreadable files: {n} image(s) that cannot be decoded, dropped by run ({detail}; "
            f"first {first['first']}: {first['reason']})"))  # fmt: skip
    cal = summary["calibration"]
    console.print(escape(f"gravity_W: {cal['gravity_W']} m/s²"))
    cams = cal["cameras"]
    for name, c in cams.items():
        if not isinstance(c, dict):
            continue
        fu, fv, cu, cv = c["intrinsics_fu_fv_cu_cv"]
        console.print(
            escape(
                f"{name}: {c['resolution'][0]}x{c['resolution'][1]} px, fu={fu:.3f} fv={fv:.3f} "
                f"cu={cu:.3f} cv={cv:.3f}, {c['distortion_model']} "
                f"[{', '.join(f'{d:.3g}' for d in c['distortion'])}]"
            )
        )
        if "z_C_in_B" in c:
            console.print(escape(
                f"  on the body: at {_vec(c['p_B_C'])} m, looking along {_vec(c['z_C_in_B'])}, "
                f"right along {_vec(c['x_C_in_B'])} (body axes), timeshift_cam_imu "
                f"{1e3 * c['timeshift_cam_imu_s']:g} ms"))  # fmt: skip
    if "baseline_m" in cams:
        console.print(
            f"stereo baseline (from T_BS of cam0/cam1): {cams['baseline_m']:.4f} m, relative "
            f"rotation {cams['relative_rotation_deg']:.3f} deg"
            + (f"; cam1 at {_vec(cams['p_C0_C1'])} m in cam0's axes (+x: right of it)"
               if "p_C0_C1" in cams else "")
        )
    if "imu" in cal:
        i = cal["imu"]
        console.print(
            f"imu0: {i['rate_hz']:g} Hz declared, gyro noise "
            f"{i['gyro_noise_density']:.4g} rad/s/√Hz, gyro bias walk "
            f"{i['gyro_random_walk']:.4g}, accel noise "
            f"{i['accel_noise_density']:.4g} m/s²/√Hz, accel bias walk {i['accel_random_walk']:.4g}"
        )
    for key in ("gps", "mag", "sonar", "features"):
        if key in cal:
            console.print(escape(f"{key}: " + ", ".join(f"{k}={v}" for k, v in cal[key].items())))
    checks = summary.get("checks", {})
    if "accel_median_mps2" in checks:
        console.print(f"imu0 accelerometer: median magnitude {checks['accel_median_mps2']:.4g} "
                      f"m/s² against gravity {checks['gravity_mps2']:.4g} (m/s², gravity "
                      "included)")  # fmt: skip
    if "gps_course_vs_gyro" in checks:
        c = checks["gps_course_vs_gyro"]
        console.print(
            f"GPS course against the gyro: cosine {c['cosine']:.2f} over {c['turns']} turns "
            f"({c['gyro_turn_deg']:.0f}° by the gyro), the course turning "
            f"{c['course_per_gyro_turn']:.3g} times as far (1: ENU-like frame, gyro in rad/s)"
        )
    if "mag_turn_vs_gyro" in checks:
        c = checks["mag_turn_vs_gyro"]
        console.print(
            f"magnetic field against the gyro: cosine {c['cosine']:.2f} over {c['turns']} turns "
            f"({c['gyro_turn_deg']:.0f}° by the gyro; +1: the field turns against the body, as "
            "it must)"
        )
    if "stereo_pair" in checks and "refused" in checks["stereo_pair"]:
        console.print(escape(f"stereo pair: refused: {checks['stereo_pair']['refused']}"))
    elif "stereo_pair" in checks:
        c = checks["stereo_pair"]
        console.print(escape(
            f"stereo pair: {c['matches']} left-right matches over {c['pairs']} pairs, "
            f"{100 * c['negative_fraction']:.1f} % at negative disparity (0: left and right in "
            f"order), rows {c['row_offset_px']:.2f} px apart (median)"
            + (f"; {c['problem']}" if c["problem"] else "")
        ))  # fmt: skip


def _print_bag(path: Path, console: Console,
               given: dict[str, str | None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Print the topics of a bag and the roles ``svains convert``/``run`` would give them
    (``given``: ``--topic`` roles); return them as JSON-ready data."""
    from dataclasses import asdict

    from svains.datasets.rosbag import bag_topics, select_topics

    topics = bag_topics(path)
    out: dict[str, Any] = {"bag": str(path), "topics": [asdict(x) for x in topics]}
    t = Table(title=escape(f"{path.name}: topics"))
    for col in ("topic", "type", "count", "rate [Hz]", "span [s]"):
        t.add_column(escape(col), justify="left" if col in ("topic", "type") else "right")
    for x in topics:
        t.add_row(escape(x.name), x.msgtype, str(x.count), _f(x.rate_hz, ".2f"), f"{x.span_s:.3f}")
    console.print(t)
    try:
        roles = select_topics(topics, given)
    except SvainsError as exc:  # ambiguous: say so, the listing above is still the answer
        console.print(escape(f"auto-detection: {exc}"))
        return {**out, "roles": None, "auto_detection": str(exc)}
    found = ", ".join(f"{k}={v}" for k, v in roles.items()) or "none"
    console.print(escape(f"auto-detected roles: {found}"))
    return {**out, "roles": roles}


def info(
    dataset: Annotated[
        Path,
        typer.Argument(help="ASL/EuRoC, TUM-VI or KITTI folder, or a ROS1/ROS2 bag."),
    ],
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write the summary as JSON.")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --json.")] = False,
    calib: Annotated[
        Path | None,
        typer.Option("--calib", help="Kalibr camchain-imucam.yaml: the cameras as run --calib "
                     "would read them."),
    ] = None,
    imu_calib: Annotated[
        Path | None, typer.Option("--imu-calib", help="Kalibr imu.yaml (noise densities).")
    ] = None,
    topic: TopicOption = None,
) -> None:
    """Describe a data set: streams, counts, rates, time span, gaps, missing files, calibration."""
    from svains.cli.run_config import topic_roles
    from svains.datasets import load_dataset
    from svains.datasets.rosbag import is_bag
    from svains.datasets.summary import dataset_summary
    from svains.outputs import atomic_write_text

    check_out_file(json_out, force, "--json")
    topics = topic_roles(topic)
    console = Console()
    try:
        bag = is_bag(dataset)
        summary = (_print_bag(dataset, console, topics) if bag else
                   dataset_summary(load_dataset(dataset, calib=calib, imu_calib=imu_calib,
                                                topics=topics)))  # fmt: skip
    except SvainsError as exc:
        fail(exc)
    if not bag:
        _print(summary, console)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(json_out, json.dumps(summary, indent=2) + "\n")
        console.print(f"wrote {json_out}")


def register(app: typer.Typer) -> None:
    app.command("info")(info)
