"""Generated reference pages: every configuration key and every command, from the code.

``configuration_page()`` walks the option dataclasses (``RunConfig``, the run's ``--set``/
``--config`` keys; ``SimConfig``, ``svains simulate --config``; ``FrontendOptions``, the front
end's Python settings) and writes one table row per key: type, default and meaning. The meaning
is taken from the source itself: the field's own comment, the class docstring (or a comment in the
class) where it introduces ``name``, and only where the source says nothing, from ``SUPPLEMENT``
below. ``cli_page()`` walks the typer application through click. Neither needs mkdocs:
``docs/hooks/mkdocs_hooks.py`` adds both pages to the site at build time, and
``tests/test_docs_config.py`` checks that every key has a meaning.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import re
import textwrap
import tokenize
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

# Meanings of the keys whose source has no comment and no docstring mention: "Class.field".
# A key listed here that no longer exists fails tests/test_docs_config.py, so it cannot go stale
# silently; a better home for a meaning is a comment or the docstring next to the field.
SUPPLEMENT: dict[str, str] = {
    # RunConfig (top level)
    "RunConfig.method": "Navigation method: `ins` (IMU with GPS, magnetometer, sonar), `vo` "
    "(stereo visual odometry, no filter), `lc` (loosely coupled egomotion), `tc` (trifocal "
    "transfer) or `3d` (3-D reconstruction with reprojection).",
    "RunConfig.model": "Filter state: `paper` (the paper's eq. 14 state, no bias states) or "
    "`biased` (with gyro and accelerometer bias states).",
    "RunConfig.filter": "Section: sigma points, propagation and gating (`FilterOptions`).",
    "RunConfig.noise": "Section: IMU noise (`NoiseOptions`).",
    "RunConfig.init": "Section: initialisation (`InitOptions`).",
    "RunConfig.use_gps": "Fuse GPS fixes (`--no-gps` turns it off).",
    "RunConfig.use_mag": "Fuse the magnetometer (`--no-mag` turns it off).",
    "RunConfig.use_sonar": "Fuse the sonar altimeter (`--no-sonar` turns it off).",
    "RunConfig.use_gps_velocity": "Fuse the GPS velocity with the position (false: position "
    "only).",
    "RunConfig.max_sonar_rate_hz": "Fuse sonar samples at most at this rate (null: every "
    "sample).",
    "RunConfig.vision": "Section: vision updates (`VisionOptions`).",
    "RunConfig.buffer": "Section: the Navigator's input buffer (`BufferOptions`).",
    "RunConfig.replay": "Section: how `svains run` replays a data set (`ReplayOptions`).",
    "RunConfig.faults": "Section: sensor-fault handling (`FaultOptions`).",
    "RunConfig.zupt": "Section: zero-velocity updates (`ZuptOptions`).",
    "RunConfig.smoother": "Section: forward-backward smoothing (`SmootherOptions`).",
    # FilterOptions
    "FilterOptions.beta": "Unscented transform's beta (2: optimal for a Gaussian prior).",
    "FilterOptions.kappa": "Unscented transform's kappa (secondary spread parameter).",
    # NoiseOptions
    "NoiseOptions.gyro_noise_density": "Gyro white-noise density (rad/s/√Hz) replacing the "
    "calibration's (null: the data set's `sensor.yaml`).",
    "NoiseOptions.gyro_random_walk": "Gyro bias random walk (rad/s²/√Hz) replacing the "
    "calibration's (null: the data set's).",
    "NoiseOptions.accel_noise_density": "Accelerometer white-noise density (m/s²/√Hz) replacing "
    "the calibration's (null: the data set's).",
    "NoiseOptions.accel_random_walk": "Accelerometer bias random walk (m/s³/√Hz) replacing the "
    "calibration's (null: the data set's).",
    "NoiseOptions.white_scale": "Factor on the IMU white-noise densities.",
    "NoiseOptions.random_walk_scale": "Factor on the IMU bias random walks.",
    # InitOptions
    "InitOptions.mode": "How the filter starts: `static` (a resting start), `gps` (in flight "
    "from GPS), `vision` (in flight from the first seconds of stereo odometry against the "
    "IMU) or `groundtruth` (the reference's first pose).",
    "InitOptions.static_s": "Length of the static interval at the start (s).",
    "InitOptions.block_s": "Length of the blocks whose IMU means test a static start (s).",
    "InitOptions.position_std": "Initial position standard deviation.",
    "InitOptions.velocity_std": "Initial velocity standard deviation.",
    "InitOptions.roll_pitch_std": "Initial roll and pitch standard deviation (static start).",
    "InitOptions.flight_roll_pitch_std": "Initial roll and pitch standard deviation.",
    "InitOptions.yaw_std": "Initial yaw standard deviation.",
    "InitOptions.yaw_std_unknown": "Initial yaw standard deviation.",
    "InitOptions.omega_std": "Initial angular-rate standard deviation.",
    "InitOptions.gyro_bias_std": "Initial gyro-bias standard deviation.",
    "InitOptions.accel_bias_std": "Initial accelerometer-bias standard deviation.",
    "InitOptions.yaw_std_local": "Initial yaw standard deviation.",
    "InitOptions.gt_velocity_std": "Initial velocity standard deviation from ground truth.",
    "InitOptions.gt_attitude_std": "Initial attitude standard deviation from ground truth.",
    "InitOptions.gt_gyro_bias_std": "Initial gyro-bias standard deviation from ground truth.",
    "InitOptions.gt_accel_bias_std": "Initial accelerometer-bias standard deviation from "
    "ground truth.",
    # VisionOptions
    "VisionOptions.min_features": "Fewest valid features for a vision update of a frame.",
    "VisionOptions.max_row_diff_px": "Largest left-right row difference of a feature in the "
    "rectified pair (px; null: no check).",
    # ZuptOptions
    "ZuptOptions.enabled": "Zero-velocity updates on.",
    # SimConfig
    "SimConfig.scenario": "`village` (the paper's rectangle around houses) or `trajectory` "
    "(a TUM file, `trajectory.tum_path`).",
    "SimConfig.duration_s": "Length of the simulated flight (s).",
    "SimConfig.seed": "Random seed of every noise draw and of the village layout.",
    "SimConfig.gravity_W": "Gravity in the world frame (m/s², z up).",
    "SimConfig.imu": "Section: the IMU (`ImuConfig`).",
    "SimConfig.gps": "Section: the GPS (`GpsConfig`).",
    "SimConfig.mag": "Section: the magnetometer (`MagConfig`).",
    "SimConfig.sonar": "Section: the sonar altimeter (`SonarConfig`).",
    "SimConfig.camera": "Section: the stereo camera (`CameraConfig`).",
    "SimConfig.world": "Section: the village (`WorldConfig`).",
    "SimConfig.trajectory": "Section: the flight path (`TrajectoryConfig`).",
    "ImuConfig.rate_hz": "IMU sample rate (Hz).",
    "ImuConfig.gyro_noise_std": "Gyro white noise per sample (rad/s).",
    "ImuConfig.accel_noise_std": "Accelerometer white noise per sample (m/s²).",
    "ImuConfig.gyro_random_walk": "Gyro bias random walk (rad/s²/√Hz).",
    "ImuConfig.accel_random_walk": "Accelerometer bias random walk (m/s³/√Hz).",
    "ImuConfig.gyro_bias_init": "Initial gyro bias in the body frame (rad/s).",
    "ImuConfig.accel_bias_init": "Initial accelerometer bias in the body frame (m/s²).",
    "GpsConfig.enabled": "Simulate the GPS.",
    "GpsConfig.rate_hz": "GPS fix rate (Hz).",
    "GpsConfig.position_noise_std": "Position noise per fix (m).",
    "GpsConfig.velocity_noise_std": "Velocity noise per fix (m/s).",
    "GpsConfig.outages": "GPS outages, `[start_s, duration_s]` pairs (s from the start).",
    "MagConfig.enabled": "Simulate the magnetometer.",
    "MagConfig.rate_hz": "Magnetometer sample rate (Hz).",
    "MagConfig.noise_std": "Field noise per sample (G).",
    "SonarConfig.enabled": "Simulate the sonar altimeter.",
    "SonarConfig.rate_hz": "Sonar sample rate (Hz).",
    "SonarConfig.noise_std": "Range noise per sample (m).",
    "CameraConfig.enabled": "Simulate the stereo camera.",
    "CameraConfig.rate_hz": "Stereo frame rate (Hz, at most 20).",
    "CameraConfig.width": "Image width (px).",
    "CameraConfig.height": "Image height (px).",
    "CameraConfig.f": "Focal length of both cameras (px).",
    "CameraConfig.cu": "Principal point, column (px).",
    "CameraConfig.cv": "Principal point, row (px).",
    "CameraConfig.brightness_period_s": "Period of the exposure change (s).",
    "CameraConfig.render_images": "Render the stereo images (false: `features0` only, much "
    "faster).",
    "WorldConfig.corner_radius": "Corner radius of the flown rectangle (m).",
    "WorldConfig.n_outer_houses": "Houses outside the rectangle.",
    "WorldConfig.n_inner_objects": "Objects inside the rectangle.",
    "WorldConfig.n_poles": "Poles along the path.",
    "WorldConfig.moving_object": "Add an object that moves through the view (a front-end "
    "outlier test).",
    "WorldConfig.moving_amplitude": "Amplitude of the moving object's motion.",
    "WorldConfig.moving_period_s": "Period of the moving object's motion (s).",
    "TrajectoryConfig.bank": "Bank into the turns of the village rectangle.",
    "TrajectoryConfig.vibration_deg": "Amplitude of the attitude vibration (deg).",
    "TrajectoryConfig.vibration_hz": "Frequency of the attitude vibration (Hz).",
    "TrajectoryConfig.tum_path": "TUM trajectory file flown by the `trajectory` scenario.",
    "TrajectoryConfig.knot_dt_s": "Knot spacing of the trajectory spline (s).",
    # Front end (Python only)
    "FrontendOptions.detector": "Section: the corner detector (`DetectorOptions`).",
    "FrontendOptions.klt": "Section: temporal KLT tracking (`KltOptions`).",
    "FrontendOptions.stereo": "Section: left-right matching (`StereoMatchOptions`).",
    "FrontendOptions.ransac": "Section: RANSAC egomotion and its covariance (`RansacOptions`).",
    "DetectorOptions.quality_level": "Shi-Tomasi quality level (`gftt`).",
    "DetectorOptions.fast_threshold": "FAST intensity threshold (`fast`).",
    "StereoMatchOptions.min_disparity_px": "Smallest disparity accepted (px).",
    "StereoMatchOptions.max_disparity_px": "Largest disparity searched (px).",
    "StereoMatchOptions.sgbm_block": "SGBM block size (px).",
    "ReacquireOptions.guided_inflation": "Variance factor on the first motion used as the "
    "guided pass's prior.",
    "ReacquireOptions.guided_min_std": "Floors (rad, m) of the guided pass's prior standard "
    "deviations.",
}


@dataclass(frozen=True)
class OptionRow:
    """One configuration key: dotted key, type, default (YAML), meaning and where it is set."""

    key: str
    type: str
    default: str
    meaning: str
    owner: str  # "Class.field"


@dataclass(frozen=True)
class OptionTree:
    """A root dataclass documented as one table: title, how users set its keys."""

    title: str
    root: type
    how: str


def option_trees() -> list[OptionTree]:
    """The documented option roots, in page order."""
    from svains.frontend.options import FrontendOptions
    from svains.navigation.options import RunConfig
    from svains.sim.config import SimConfig

    return [
        OptionTree(
            "Run configuration (`RunConfig`)", RunConfig,
            "`svains run`/`svains compare` `--set key=value` (repeatable), a `--config` YAML "
            "file (any subset, nested by section), `config.yaml` beside every run, and "
            "`svains.RunConfig` in Python. A campaign spec's `settings` reach them through one "
            "adapter ([Campaigns](campaigns.md#run-settings)).",
        ),
        OptionTree(
            "Simulator (`SimConfig`)", SimConfig,
            "`svains simulate --config YAML` (any subset, nested by section) and a campaign "
            "spec's `scenarios`; `scenario.yaml` beside every simulated data set holds them all.",
        ),
        OptionTree(
            "Front end (`FrontendOptions`, Python only)", FrontendOptions,
            "`svains.frontend.pipeline.StereoFrontend(..., options=FrontendOptions(...))`; not "
            "a command-line setting.",
        ),
    ]


# --- reading the source --------------------------------------------------------------------

_UNIT_RE = re.compile(r"^(m|s|px|rad|deg|G|Hz|m²|m/s|m/s²|rad/s|rad/s²)(?=$|[ ,;(])")


@dataclass(frozen=True)
class _ClassSource:
    doc: str  # the class docstring
    comments: str  # every comment in the class body, joined
    inline: dict[str, str]  # field -> comment on its own line
    above: dict[str, str]  # field -> comment block directly above it


def _class_source(cls: type) -> _ClassSource:
    """Docstring and comments of a dataclass, from its source text."""
    src = textwrap.dedent(inspect.getsource(cls))
    tree = ast.parse(src)
    node = tree.body[0]
    assert isinstance(node, ast.ClassDef)
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = src.splitlines()
    inline: dict[str, str] = {}
    above: dict[str, str] = {}
    for stmt in node.body:
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        name = stmt.target.id
        for ln in range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1):
            if ln in comments and not lines[ln - 1].lstrip().startswith("#"):
                inline[name] = comments[ln]
                break
        block: list[str] = []
        ln = stmt.lineno - 1
        while ln >= 1 and lines[ln - 1].lstrip().startswith("#"):
            block.insert(0, comments.get(ln, ""))
            ln -= 1
        if block and not any(t.startswith("fmt:") for t in block):
            above[name] = " ".join(block)
    body_comments = " ".join(
        text for ln, text in sorted(comments.items())
        if lines[ln - 1].lstrip().startswith("#") and not text.startswith("fmt:")
    )  # fmt: skip
    return _ClassSource(inspect.getdoc(cls) or "", body_comments, inline, above)


def _clauses(text: str) -> list[str]:
    """``text`` cut at ``;`` and at sentence ends outside parentheses."""
    text = " ".join(text.split())
    out: list[str] = []
    depth = 0
    start = 0
    for i, ch in enumerate(text):
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth = max(0, depth - 1)
        elif depth == 0 and ch in ";." and text[i + 1 : i + 2] in (" ", ""):
            nxt = text[i + 2 : i + 3]
            if ch == ";" or nxt == "" or nxt.isupper() or nxt == "`":
                out.append(text[start : i + 1].strip())
                start = i + 1
    if text[start:].strip():
        out.append(text[start:].strip())
    return [c for c in out if c]


def _markdown(text: str) -> str:
    """Docstring text as one Markdown table cell: RST literals as code, no bare pipes."""
    text = " ".join(text.split()).replace("``", "`")
    text = re.sub(r"\bNone\b", "null", text.rstrip(";").strip())
    if text and text[-1] not in ".)`":
        text += "."
    return text.replace("|", "\\|")


def _literal_re(name: str) -> re.Pattern[str]:
    """A double-backtick literal that holds ``name`` as a whole word (``name=False``, ...)."""
    return re.compile(r"``[^`]*(?<![\w.])" + re.escape(name) + r"(?!\w)[^`]*``")


def _is_unit(comment: str) -> bool:
    """A comment that only gives a unit, possibly with a parenthesis: "m", "rad (in flight)"."""
    m = _UNIT_RE.match(comment)
    return bool(m) and (comment[m.end():].strip() == "" or comment[m.end():].lstrip()[0] == "(")


def field_meaning(cls: type, name: str, source: _ClassSource | None = None) -> str:
    """What field ``name`` of dataclass ``cls`` means, from its source; "" when it says nothing.

    In order: a clause of the docstring (or of a comment in the class) that starts with a
    literal naming the field; the comment block directly above the field; ``SUPPLEMENT``; the
    field's own comment, when it is more than a unit; a clause that mentions the field. The
    field's own comment, when it is not the meaning, is appended to it ("m", "Table 1: ...").
    """
    src = source or _class_source(cls)
    pattern = _literal_re(name)
    clauses = _clauses(src.doc) + _clauses(src.comments)
    units = [c for c in (src.above.get(name, ""), src.inline.get(name, "")) if _is_unit(c)]
    above = "" if _is_unit(src.above.get(name, "")) else src.above.get(name, "")
    inline = "" if _is_unit(src.inline.get(name, "")) else src.inline.get(name, "")
    candidates = (
        next((c for c in clauses if (m := pattern.search(c)) and m.start() == 0), ""),
        above,
        SUPPLEMENT.get(f"{cls.__name__}.{name}", ""),
        inline,
        next((c for c in clauses if pattern.search(c)), ""),
    )
    found = next((c for c in candidates if c), "")
    if not found:
        return ""
    text = _markdown(found)
    for note in [*units, inline]:
        if note and note not in found:
            text += f" *[{_markdown(note).rstrip('.')}]*"
    return text


def meaning_sources(cls: type, name: str) -> list[str]:
    """Which sources describe a field, of "definition", "above", "inline", "supplement",
    "mention" (``tests/test_docs_config.py`` keeps ``SUPPLEMENT`` free of shadowed entries)."""
    src = _class_source(cls)
    pattern = _literal_re(name)
    clauses = _clauses(src.doc) + _clauses(src.comments)
    found = {
        "definition": any((m := pattern.search(c)) and m.start() == 0 for c in clauses),
        "above": bool(src.above.get(name)) and not _is_unit(src.above[name]),
        "inline": bool(src.inline.get(name)) and not _is_unit(src.inline[name]),
        "supplement": f"{cls.__name__}.{name}" in SUPPLEMENT,
        "mention": any(pattern.search(c) for c in clauses),
    }
    return [k for k, v in found.items() if v]


def _type_text(tp: Any) -> str:
    """A readable type: ``float | null``, ``one of a, b``, ``[float, float]``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Literal:
        return "one of " + ", ".join(str(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("null" if a is type(None) else _type_text(a) for a in args)
    if origin in (tuple, list):
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_text(args[0])}"
        if origin is list:
            return f"list of {_type_text(args[0])}" if args else "list"
        return "[" + ", ".join(_type_text(a) for a in args) + "]"
    if dataclasses.is_dataclass(tp):
        return "section"
    return getattr(tp, "__name__", str(tp))


def _default_text(value: Any) -> str:
    """A default as YAML (what ``--set`` and the configuration files take)."""
    if dataclasses.is_dataclass(value):
        return "(section)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_default_text(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _default_of(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def option_rows(root: type, prefix: str = "") -> Iterator[OptionRow]:
    """Every key of dataclass ``root`` (sections first as a row of their own, then their keys)."""
    hints = typing.get_type_hints(root)
    source = _class_source(root)
    for f in dataclasses.fields(root):
        default = _default_of(f)
        key = f"{prefix}{f.name}"
        yield OptionRow(
            key=key,
            type=_type_text(hints[f.name]),
            default="(required)" if default is dataclasses.MISSING else _default_text(default),
            meaning=field_meaning(root, f.name, source),
            owner=f"{root.__name__}.{f.name}",
        )
        if dataclasses.is_dataclass(hints[f.name]):
            yield from option_rows(hints[f.name], f"{key}.")


def all_option_rows() -> list[OptionRow]:
    """Every row of every documented option tree."""
    return [row for tree in option_trees() for row in option_rows(tree.root)]


def configuration_page() -> str:
    """The Markdown of the configuration page."""
    out = [
        "# Configuration",
        "",
        "Every option key with its default and meaning, generated from the option dataclasses "
        "each time the site is built (`docs/hooks/reference_pages.py`), so this page lists "
        "exactly what the code accepts. Values are YAML: `true`/`false`, `null`, numbers, "
        "strings, lists `[a, b]`.",
        "",
        "```",
        "svains run DATA --method 3d --images --set vision.frame_stride=5 \\",
        "    --set faults.consistency=false",
        "svains run DATA --config OUT/config.yaml     # a previous run's every key: same result",
        "svains simulate --out SIM --config sim.yaml  # e.g. camera: {rate_hz: 5.0}",
        "```",
        "",
        "An unknown key or a value of the wrong type is refused with the dotted key in the "
        "message (`--set`: a usage error, exit 2; in a `--config` file: exit 1). A bare vision "
        "key (`--set frame_stride=5`) means `vision.frame_stride`. Precedence: defaults < "
        "`--config` < the command's switches (`--no-gps`, `--rotation`, ...) < `--set`.",
        "",
    ]
    for tree in option_trees():
        out += [f"## {tree.title}", "", tree.how, "", "| key | type | default | meaning |",
                "|---|---|---|---|"]  # fmt: skip
        for row in option_rows(tree.root):
            key = f"**`{row.key}`**" if row.default == "(section)" else f"`{row.key}`"
            out.append(f"| {key} | {row.type} | `{row.default}` | {row.meaning} |")
        out.append("")
    return "\n".join(out)


# --- the command line ---------------------------------------------------------------------


def _usage(name: str, cmd: Any, ctx: Any) -> str:
    args = [p.name.upper() for p in cmd.get_params(ctx) if p.param_type_name == "argument"]
    return " ".join(["svains", name, "[OPTIONS]", *args]).replace("  ", " ")


def _param_rows(cmd: Any, ctx: Any) -> list[str]:
    rows = []
    for p in cmd.get_params(ctx):
        record = p.get_help_record(ctx)
        if record is None:
            continue
        opts, help_text = record
        help_text = " ".join(help_text.split()).replace("|", "\\|").replace("<", "&lt;")
        rows.append(f"| `{opts}` | {help_text} |")
    return rows


def cli_page() -> str:
    """The Markdown of the command-line page, from the typer application."""
    import click
    import typer

    from svains.cli.main import app

    group = typer.main.get_command(app)
    ctx = click.Context(group, info_name="svains")
    out = [
        "# Command line",
        "",
        "Generated from the typer application (`svains.cli.main`) each time the site is built: "
        "the same text as `svains COMMAND --help`.",
        "",
        "```",
        "svains [--verbose] [--threads N] COMMAND [OPTIONS] ARGS",
        "```",
        "",
        inspect.cleandoc(group.help or ""),
        "",
        "Exit codes, the same for every command: `0` success; `1` bad data or input; `2` usage "
        "(see [Faults and bad input](results/faults.md#exit-codes)). Ctrl-C exits 130.",
        "",
        "## Global options",
        "",
        "| option | meaning |",
        "|---|---|",
        *_param_rows(group, ctx),
        "",
    ]
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        sub = click.Context(cmd, info_name=name, parent=ctx)
        out += [
            f"## svains {name}",
            "",
            "```",
            _usage(name, cmd, sub),
            "```",
            "",
            " ".join(inspect.cleandoc(cmd.help or "").split()),
            "",
            "| argument or option | meaning |",
            "|---|---|",
            *_param_rows(cmd, sub),
            "",
        ]
    return "\n".join(out)


if __name__ == "__main__":
    import sys

    pages = {"configuration": configuration_page, "cli": cli_page}
    if len(sys.argv) != 2 or sys.argv[1] not in pages:
        sys.exit("usage: python docs/hooks/reference_pages.py configuration|cli")
    print(pages[sys.argv[1]]())
