"""``svains convert BAG --out DIR``: a ROS1/ROS2 bag to the ASL layout, calibration from Kalibr."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from svains.cli._common import fail
from svains.errors import SvainsError

_TOPIC_HELP = "topic (default: auto-detected from message types and names)"


def convert(
    bag: Annotated[Path, typer.Argument(help="ROS1 .bag, ROS2 .db3/.mcap file or bag folder.")],
    out: Annotated[Path, typer.Option("--out", help="Output data-set folder (gets mav0/).")],
    calib: Annotated[
        Path | None, typer.Option("--calib", help="Kalibr camchain-imucam.yaml (cameras).")
    ] = None,
    imu_calib: Annotated[
        Path | None, typer.Option("--imu-calib", help="Kalibr imu.yaml (IMU noise).")
    ] = None,
    imu: Annotated[str | None, typer.Option("--imu", help=f"IMU {_TOPIC_HELP}.")] = None,
    left: Annotated[str | None, typer.Option("--left", help=f"Left image {_TOPIC_HELP}.")] = None,
    right: Annotated[
        str | None, typer.Option("--right", help=f"Right image {_TOPIC_HELP}.")
    ] = None,
    gps: Annotated[str | None, typer.Option("--gps", help=f"NavSatFix {_TOPIC_HELP}.")] = None,
    gt: Annotated[
        str | None, typer.Option("--gt", help=f"Ground-truth pose {_TOPIC_HELP}.")
    ] = None,
) -> None:
    """Convert BAG into an ASL/EuRoC folder: IMU, stereo images, GPS (local ENU), ground truth."""
    from svains.datasets.rosbag_convert import convert_bag

    topics = {"imu": imu, "left": left, "right": right, "gps": gps, "gt": gt}
    try:
        rep = convert_bag(bag, out, topics, calib, imu_calib)
    except SvainsError as exc:
        fail(exc)
    console = Console()
    t = Table(title=escape(f"{bag.name} -> {out}/mav0"))
    for col in ("stream", "samples"):
        t.add_column(col)
    for name, n in rep.counts.items():
        t.add_row(name, str(n))
    console.print(t)
    console.print(escape("topics: " + ", ".join(f"{k}={v}" for k, v in rep.topics.items())))
    console.print(f"converted in {rep.wall_s:.2f} s ({rep.cpu_s:.2f} s CPU)")


def register(app: typer.Typer) -> None:
    app.command("convert")(convert)
