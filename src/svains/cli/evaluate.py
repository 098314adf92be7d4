"""``svains evaluate EST GT``: ATE (se3/posyaw/none/sim3 alignment) and RPE, equal to evo's."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from svains.cli._common import check_out_file, fail, positive_finite, usage_error
from svains.errors import SvainsError


def _num(v: float, fmt: str = ".4f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


TILT_NOTE_DEG = 1.0  # deg of tilt by the se3/sim3 fit above which evaluate says so


def evaluate(
    est: Annotated[
        Path, typer.Argument(help="Estimate: TUM, EuRoC data.csv, KITTI poses or a ROS bag.")
    ],
    gt: Annotated[
        Path,
        typer.Argument(help="Reference: same formats, or a data-set folder with ground truth."),
    ],
    align: Annotated[
        str, typer.Option("--align", help="Alignment: se3, posyaw, none or sim3.")
    ] = "se3",
    delta: Annotated[
        list[float] | None,
        typer.Option("--delta", help="RPE segment length in metres (repeatable; default 1 and 5)."),
    ] = None,
    max_diff: Annotated[
        float,
        typer.Option("--max-diff", help="Max time difference in seconds to pair poses.",
                     callback=positive_finite),
    ] = 0.01,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the results as JSON.")
    ] = None,
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            help="Format of both files (tum, euroc, kitti, bag, dataset, states; a data-set folder "
            "given as reference is read as one); default: detected.",
        ),
    ] = None,
    ref_format: Annotated[
        str | None, typer.Option("--ref-format", help="Format of the reference, if different.")
    ] = None,
    est_topic: Annotated[
        str | None, typer.Option("--est-topic", help="Pose topic when EST is a bag.")
    ] = None,
    ref_topic: Annotated[
        str | None, typer.Option("--ref-topic", help="Pose topic when GT is a bag.")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --json.")] = False,
) -> None:
    """ATE and RPE of an estimate against ground truth (numbers as evo_ape / evo_rpe)."""
    from svains.datasets.trajectory_formats import FORMATS
    from svains.evaluation.metrics import ALIGNMENTS
    from svains.evaluation.report import evaluate_files

    if align not in ALIGNMENTS:
        usage_error(f"must be one of {', '.join(ALIGNMENTS)}, got {align!r}", "--align")
    for name, value in (("--format", fmt), ("--ref-format", ref_format)):
        if value is not None and value not in FORMATS:
            usage_error(f"must be one of {', '.join(FORMATS)}, got {value!r}", name)
    check_out_file(json_out, force, "--json")
    try:
        deltas = delta if delta else [1.0, 5.0]
        rep = evaluate_files(
            est, gt, align=align, delta_m=deltas, max_diff_s=max_diff,  # type: ignore[arg-type]
            # a data-set folder given as reference is read as one whatever --format says
            est_format=fmt,  # type: ignore[arg-type]
            ref_format=ref_format or (None if gt.is_dir() else fmt),  # type: ignore[arg-type]
            est_topic=est_topic, ref_topic=ref_topic,
        )  # fmt: skip
    except SvainsError as exc:
        fail(exc)
    console = Console()
    a = rep.ate
    t = Table(title=f"ATE \\[m], {a.alignment} alignment, {a.n} matched poses")
    for col in ("rmse", "mean", "median", "std", "min", "max", "rot rmse [deg]"):
        t.add_column(escape(col), justify="right")
    t.add_row(*(_num(v) for v in (a.rmse, a.mean, a.median, a.std, a.min, a.max)),
              _num(a.rot_rmse_deg, ".3f"))  # fmt: skip
    console.print(t)
    if a.alignment == "sim3":
        console.print(f"sim3 scale: {a.scale:.6f}")
    if a.alignment in ("se3", "sim3") and a.fit_tilt_deg > TILT_NOTE_DEG:
        # A gravity-aligned estimate (every svains run) keeps its tilt under posyaw; a fit that
        # tilts it makes the rotation column the fit's (KITTI raw 3d: 6.95° after se3, 0.64°
        # after posyaw, 0.11° of RPE).
        console.print(f"note: the {a.alignment} fit tilted the estimate by {a.fit_tilt_deg:.2f}° "
                      "(z-up worlds); its rotation errors are the fit's. For a gravity-aligned "
                      "estimate use --align posyaw.", soft_wrap=True)  # fmt: skip
    r = Table(title="RPE over travelled distance")
    for col in ("delta [m]", "pairs", "trans rmse [m]", "trans mean [m]", "trans max [m]",
                "rot rmse [deg]"):  # fmt: skip
        r.add_column(escape(col), justify="right")
    for x in rep.rpe:
        r.add_row(_num(x.delta_m, "g"), str(x.n_pairs), _num(x.trans_rmse), _num(x.trans_mean),
                  _num(x.trans_max), _num(x.rot_rmse_deg, ".3f"))  # fmt: skip
    console.print(r)
    if json_out is not None:
        rep.to_json(json_out)
        console.print(f"wrote {json_out}")


def register(app: typer.Typer) -> None:
    app.command("evaluate")(evaluate)
