"""The run configuration from the command line: ``--config FILE``, switches, ``--set k=v``.

Precedence: defaults < ``--config`` file < explicit switches (``--method``, ``--no-gps``, ...)
< ``--set section.key=value`` (any key of ``RunConfig``; a bare vision key such as
``frame_stride=4`` means ``vision.frame_stride``). ``effective_config_text`` is what
``OUT/config.yaml`` holds: the configuration resolved against the data set, under a comment
header naming the svains version, the git revision and the data set.
"""

from __future__ import annotations

import dataclasses
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

from svains.cli._common import parse_outage, usage_error
from svains.errors import ConfigError


def gps_off_switches(
    gps_outage: list[str] | None, gps_until: float | None
) -> dict[str, Any]:
    """``gps_outages``/``gps_until_s`` switches from ``--gps-outage`` (repeatable) and
    ``--gps-until`` (``None`` = not given)."""
    return {
        "gps_outages": None if not gps_outage else [list(parse_outage(g)) for g in gps_outage],
        "gps_until_s": gps_until,
    }


def kalibr_switches(calib: Path | None, imu_calib: Path | None) -> dict[str, str | None]:
    """``replay.calib``/``replay.imu_calib`` switches from ``--calib``/``--imu-calib``: absolute
    paths, so that ``OUT/config.yaml`` finds the files from any working directory."""
    return {
        "replay.calib": None if calib is None else str(calib.resolve()),
        "replay.imu_calib": None if imu_calib is None else str(imu_calib.resolve()),
    }


def topic_roles(topic: list[str] | None) -> dict[str, str | None] | None:
    """The roles of ``--topic ROLE=TOPIC`` (repeatable; None: not given), checked: a usage
    error (exit 2) names a malformed item."""
    from svains.datasets.rosbag import parse_topic_roles

    try:
        return parse_topic_roles(",".join(t.strip() for t in topic or ()))
    except ConfigError as exc:
        usage_error(str(exc).removeprefix("replay.topics (--topic): "), "--topic")


def topic_switches(topic: list[str] | None) -> dict[str, str | None]:
    """The ``replay.topics`` switch from ``--topic`` (``topic_roles``), in one spelling."""
    from svains.datasets.rosbag import topic_roles_text

    roles = topic_roles(topic)
    return {"replay.topics": None if roles is None else topic_roles_text(roles)}


def build_config(
    config_file: Path | None, settings: list[str] | None, switches: dict[str, Any]
) -> Any:
    """``RunConfig`` from a file, the switches given (``None`` = not given; dotted keys) and
    ``--set`` items."""
    from svains.navigation.config_io import from_yaml, parse_setting, with_settings
    from svains.navigation.options import RunConfig, VisionOptions

    config = RunConfig() if config_file is None else from_yaml(config_file)
    given = {k: v for k, v in switches.items() if v is not None}
    top = {f.name for f in dataclasses.fields(RunConfig)}
    vision = {f.name for f in dataclasses.fields(VisionOptions)}
    for item in settings or []:
        try:
            key, value = parse_setting(item)
            if "." not in key and key not in top and key in vision:
                key = f"vision.{key}"
            with_settings(RunConfig(), {key: value})  # the key and the value's type
        except ConfigError as exc:
            usage_error(str(exc), "--set")
        given[key] = value
    try:
        config = with_settings(config, given)
    except ConfigError as exc:
        if config_file is not None:
            raise  # (the file's: exit 1, as its other errors)
        # options that do not go together on the command line are a usage error, as
        # ``--smooth`` with ``vo`` is (exit 2)
        usage_error(str(exc), None)
    # Kalibr files however given (--set, a --config file) as absolute paths, read as the run
    # reads them: OUT/config.yaml then finds them from anywhere (a review: `svains plot` from
    # another folder missed a relative one)
    replay = config.replay
    files = {k: str(Path(v).resolve()) for k in ("calib", "imu_calib")
             if isinstance(v := getattr(replay, k), str) and not Path(v).is_absolute()}
    if not files:
        return config
    return dataclasses.replace(config, replay=dataclasses.replace(replay, **files))


# sections and top-level keys only a filter reads: ``vo`` (a chain of stereo motions) ignores
# them
FILTER_ONLY_KEYS = ("filter", "noise", "init", "zupt", "smoother", "faults", "model", "use_gps",
                   "use_mag", "use_sonar", "use_gps_velocity", "max_mag_rate_hz",
                   "max_sonar_rate_hz")


def filter_only_settings(settings: list[str] | None) -> list[str]:
    """The ``--set`` keys of ``settings`` that only a filter reads (``FILTER_ONLY_KEYS``), in
    their order: ``vo`` runs without them, which a user setting them is told."""
    from svains.navigation.config_io import parse_setting

    keys = [parse_setting(item)[0] for item in settings or []]
    return [k for k in keys if k.split(".", 1)[0] in FILTER_ONLY_KEYS]


def _git_revision() -> str:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                             text=True, timeout=5, check=True)  # fmt: skip
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=here, capture_output=True, text=True, timeout=5)  # fmt: skip
        return out.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def effective_config_text(config: Any, dataset: Path) -> str:
    """YAML of the effective configuration under a comment header (version, revision, data)."""
    from svains.navigation.config_io import to_yaml

    try:
        version = metadata.version("svains")
    except metadata.PackageNotFoundError:
        version = "unknown"
    header = (f"svains run configuration (effective: resolved against the data set)\n"
              f"svains {version}, git {_git_revision()}\ndata set: {dataset}")  # fmt: skip
    return to_yaml(config, header=header)
