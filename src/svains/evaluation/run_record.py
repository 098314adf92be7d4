"""A finished run read back from its folder (what ``svains run --out DIR`` wrote), for plots and
the viewer.

Files (``docs/formats.md``): ``states.csv`` and ``report.json`` always; optionally, per-update
logs the runner may add:

- ``updates.csv``: ``t_ns,sensor,nis,dof,accepted`` (one row per measurement update: the
  normalised innovation squared, its degrees of freedom, 1 if it passed the chi-square gate);
- ``tracks.csv``: ``t_ns,track_id,u_px,v_px,inlier`` (left raw-image pixel of every feature at
  every stereo frame, 1 if the update used it, 0 for an outlier or a gated feature).
"""

from __future__ import annotations

import functools
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import GroundTruth
from svains.errors import DatasetError
from svains.evaluation.accuracy import aligned_for_errors, reference_at
from svains.evaluation.reference_tilt import leveling_rotation
from svains.replay.groundtruth import navigation_errors

log = logging.getLogger(__name__)

# What ``plot_run`` may write (``time_offset.png`` for runs that estimated the offset).
PLOT_NAMES = ("errors.png", "nees.png", "measurements.png", "time_offset.png")

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class RunRecord:
    """``t_ns`` (N,), states ``x`` (N, nx), tangent standard deviations ``std`` (N, ndx) (NaN
    without covariance), ``report`` (report.json), and the optional per-update logs (column name
    -> array) or None."""

    run_dir: Path
    t_ns: I64
    x: F64
    std: F64
    report: dict[str, Any]
    updates: dict[str, NDArray[Any]] | None
    tracks_path: Path | None = None

    @functools.cached_property
    def tracks(self) -> dict[str, NDArray[Any]] | None:
        """``tracks.csv``'s columns, read on first use (an hour's run writes 770 MB of them,
        which ``svains plot`` never needed: 103 s and 7.4 GB instead of 8 s, a user's probe)."""
        return None if self.tracks_path is None else _numeric_columns(self.tracks_path)


def _csv_columns(path: Path, text_cols: tuple[str, ...] = ()) -> dict[str, NDArray[Any]]:
    """A headed CSV as columns: ``t_ns`` int64, ``text_cols`` str, the rest float64."""
    lines = path.read_text().splitlines()
    if not lines:
        raise DatasetError(f"{path}: empty file")
    names = [n.strip().lstrip("#") for n in lines[0].split(",")]
    rows = [ln.split(",") for ln in lines[1:] if ln.strip()]
    bad = next((k for k, r in enumerate(rows, start=2) if len(r) != len(names)), None)
    if bad is not None:
        raise DatasetError(f"{path}:{bad}: expected {len(names)} fields")
    cols = list(zip(*rows, strict=True)) if rows else [()] * len(names)
    out: dict[str, NDArray[Any]] = {}
    try:
        for name, col in zip(names, cols, strict=True):
            if name == "t_ns" or name == "track_id":
                out[name] = np.array([int(v) for v in col], dtype=np.int64)
            elif name in text_cols:
                out[name] = np.array([v.strip() for v in col], dtype=str)
            else:
                out[name] = np.array(col, dtype=float)
    except ValueError as exc:
        raise DatasetError(f"{path}: malformed value: {exc}") from None
    return out


def _numeric_columns(path: Path) -> dict[str, NDArray[Any]]:
    """As ``_csv_columns`` for a file of numbers only, parsed by numpy (a long run's
    ``tracks.csv`` holds millions of rows); a malformed file is read again to say where."""
    with path.open() as f:
        header = f.readline()
        if not header.strip() or not f.readline().strip():
            # empty (a run cut short) or a header alone: the plain reader says so or reads it
            # (numpy returned {'': []} for the one and warned twice for the other: a review)
            return _csv_columns(path)
    names = [n.strip().lstrip("#") for n in header.split(",")]
    ints = [k for k, n in enumerate(names) if n in ("t_ns", "track_id")]
    floats = [k for k in range(len(names)) if k not in ints]
    try:
        out: dict[str, NDArray[Any]] = {}
        for cols, dtype in ((ints, np.int64), (floats, np.float64)):
            if cols:
                a = np.loadtxt(path, delimiter=",", skiprows=1, usecols=cols, dtype=dtype,
                               ndmin=2)  # fmt: skip
                out.update({names[c]: a[:, j].copy() for j, c in enumerate(cols)})
    except ValueError:
        return _csv_columns(path)  # raises naming the line, or parses what numpy would not
    return {n: out[n] for n in names}


def replay_sources(run_dir: Path | str) -> dict[str, Any]:
    """The calibration files and bag topics a run read its data set with (its ``config.yaml``'s
    ``replay.calib``, ``replay.imu_calib`` and ``replay.topics``), as ``load_dataset``'s
    keywords; none when the run has no readable ``config.yaml`` (a run of the Python API)."""
    import yaml

    from svains.datasets.rosbag import parse_topic_roles

    try:
        text = (Path(run_dir) / "config.yaml").read_text(encoding="utf-8")
        replay = (yaml.safe_load(text) or {}).get("replay") or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, AttributeError):
        return {}
    if not isinstance(replay, dict):
        return {}
    out: dict[str, Any] = {}
    for key in ("calib", "imu_calib"):
        name = replay.get(key)
        if not isinstance(name, str) or not name:
            continue
        if Path(name).is_file():
            out[key] = name
        else:  # moved since, or relative to where the run was started: the data set's own
            log.warning("%s names replay.%s %s, which is not found: the data set is read with "
                        "its own calibration", Path(run_dir) / "config.yaml", key, name)
    topics = replay.get("topics")
    if isinstance(topics, str) and topics.strip():
        out["topics"] = parse_topic_roles(topics)
    return out


def read_run(run_dir: Path | str, smoothed: bool = False) -> RunRecord:
    """Read ``states.csv``, ``report.json`` and, when present, ``updates.csv``/``tracks.csv``;
    with ``smoothed``, the smoothed states (``states_smoothed.csv``, ``svains run --smooth``)."""
    d = Path(run_dir)
    states = "states_smoothed.csv" if smoothed else "states.csv"
    for name in (states, "report.json"):
        if not (d / name).is_file():
            hint = "run it with --smooth" if smoothed else "see svains run --out"
            raise DatasetError(f"{d}: not a run folder (missing {name}; {hint})")
    cols = _csv_columns(d / states)
    names = list(cols)
    std_names = [n for n in names if n.startswith("std_")]
    x_names = [n for n in names if n != "t_ns" and not n.startswith("std_")]
    x = np.stack([cols[n] for n in x_names], axis=1) if x_names else np.zeros((0, 0))
    std = np.stack([cols[n] for n in std_names], axis=1) if std_names else np.zeros((0, 0))
    upd = _csv_columns(d / "updates.csv", ("sensor",)) if (d / "updates.csv").is_file() else None
    trk = d / "tracks.csv" if (d / "tracks.csv").is_file() else None
    report = json.loads((d / "report.json").read_text())
    return RunRecord(d, cols["t_ns"], x, std, report, upd, trk)


@dataclass(frozen=True)
class RunErrors:
    """Errors ``truth ⊟ estimate`` after the run's ``errors_alignment``: ``t_ns`` (M,), ``e``
    (M, 9) position m, velocity m/s, attitude rad (body axes), ``std`` (M, 9) the matching
    standard deviations, ``nees`` (M,) from those (diagonal covariance, 9 dof); ``x`` (M, nx)
    the aligned states and ``p_ref`` (M, 3) m the ground-truth positions, in its world."""

    t_ns: I64
    e: F64
    std: F64
    nees: F64
    alignment: str
    x: F64
    p_ref: F64


def run_errors(rec: RunRecord, gt: GroundTruth, up_W: F64 | None = None) -> RunErrors:
    """The per-state errors of a run against ground truth, aligned as ``report.json`` says.

    ``states.csv`` keeps standard deviations only, so the covariance is taken diagonal: the NEES
    here differs from ``report.json``'s ``nees_mean`` (full covariance) by the cross terms.
    When the report removed the reference's tilt (``reference_tilt_deg``), the ground truth is
    levelled the same way (``reference_gravity``'s ``g_Wr_mps2`` onto ``-up_W``).
    """
    up = np.array([0.0, 0.0, 1.0]) if up_W is None else np.asarray(up_W, float)
    R_W_Wref = None
    grav = rec.report.get("reference_gravity")
    if rec.report.get("reference_tilt_deg") is not None and isinstance(grav, dict):
        R_W_Wref = leveling_rotation(grav["g_Wr_mps2"], -up)
    inside, p, v, q = reference_at(gt, rec.t_ns, R_W_Wref)
    if inside.sum() < 2:
        raise DatasetError(f"{rec.run_dir}: the run and the ground truth do not overlap in time")
    x, std = rec.x[inside], rec.std[inside, :9]
    P = np.einsum("ni,ij->nij", np.nan_to_num(std, nan=0.0) ** 2, np.eye(9))
    # the report's own alignment (a start_position run was plotted unaligned, 22 m off: a
    # review)
    x, P, align = aligned_for_errors(rec.t_ns[inside], x, P, p, q,
                                     str(rec.report.get("errors_alignment") or "none"), up)
    e = navigation_errors(x, p, v, q)
    s = np.sqrt(np.einsum("nii->ni", P))
    with np.errstate(divide="ignore", invalid="ignore"):
        nees = np.sum((e / s) ** 2, axis=1)
    if not np.isfinite(std).all():
        nees = np.full(len(e), np.nan)  # no covariance (VO)
    return RunErrors(rec.t_ns[inside], e, s, nees, align, x, p)
