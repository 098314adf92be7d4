"""Read a trajectory in any format ``svains evaluate`` takes, auto-detected or named.

- ``tum``: ``t x y z qx qy qz qw``, t in seconds (``datasets/trajectory.py``);
- ``euroc``: an EuRoC/ASL ``data.csv``, ground truth (17 columns) or mocap (8), starting
  ``t [ns], p xyz, q wxyz``;
- ``kitti``: KITTI poses, 12 numbers per line (3x4 ``T_W_C`` row-major); times from
  ``times.txt`` beside the file, else pose i at i seconds;
- ``bag``: a pose topic of a ROS bag (``datasets/rosbag.py``), header stamps;
- ``dataset``: a data-set folder's ground truth;
- ``states``: a run's ``states.csv`` (``t_ns``, ``p_W_B_*``, ``v_W_B_*``, ``q_W_B_*``, ...).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from svains.datasets._textio import parse_floats, parse_timestamps, read_csv_rows
from svains.datasets.trajectory import read_tum
from svains.errors import DatasetError

if TYPE_CHECKING:
    from svains.sensors.types import GroundTruth

log = logging.getLogger(__name__)

TrajectoryFormat = Literal["tum", "euroc", "kitti", "bag", "dataset", "states"]
FORMATS: tuple[str, ...] = ("tum", "euroc", "kitti", "bag", "dataset", "states")
# The first columns of a run's states.csv (``replay.writers``)
STATES_HEADER = "t_ns,p_W_B_x,p_W_B_y,p_W_B_z,v_W_B_x,v_W_B_y,v_W_B_z,q_W_B_w,q_W_B_x"
Trajectory = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]


def _first_row(path: Path) -> tuple[list[str], bool]:
    """Fields of the first data row and whether they are comma separated."""
    with path.open(errors="replace") as fh:
        for line in fh:
            s = line.strip()
            if s and not s.startswith("#"):
                return (s.split(","), True) if "," in s else (s.split(), False)
    raise DatasetError(f"{path}: no data rows")


def detect_format(path: Path) -> TrajectoryFormat:
    """The format of ``path`` from its kind, suffix and first data row."""
    from svains.datasets.rosbag import is_bag

    if is_bag(path):
        return "bag"
    if path.is_dir():
        return "dataset"
    if not path.is_file():
        raise DatasetError(f"missing file: {path}")
    with path.open(errors="replace") as fh:
        if fh.readline().startswith(STATES_HEADER):
            return "states"
    row, commas = _first_row(path)
    if len(row) == 12:
        return "kitti"
    if commas and len(row) in (8, 17):
        return "euroc"
    if len(row) == 8:
        return "tum"
    raise DatasetError(
        f"{path}: cannot tell the trajectory format from a first row of {len(row)} fields "
        f"(TUM 8, EuRoC csv 8 or 17, KITTI 12, a run's states.csv); pass --format"
    )


def read_euroc_csv(path: Path) -> Trajectory:
    """An EuRoC ``data.csv`` with ``t [ns], p xyz, q wxyz`` first (17 or 8 columns)."""
    n = len(_first_row(path)[0])
    if n not in (8, 17):
        raise DatasetError(f"{path}: an EuRoC pose csv has 8 or 17 columns, found {n}")
    rows, lines = read_csv_rows(path, n)
    t = parse_timestamps(path, rows, lines)
    a = parse_floats(path, rows, lines, slice(1, 8))
    return t, a[:, 0:3].copy(), a[:, 3:7].copy()


def read_states_csv(path: Path) -> Trajectory:
    """A run's ``states.csv``: its stamps, positions and ``q_W_B`` (w first) columns (a probe
    found it unreadable by ``svains evaluate``)."""
    with path.open(errors="replace") as fh:
        header = fh.readline().strip()
    if not header.startswith(STATES_HEADER):
        raise DatasetError(f"{path}: not a svains states.csv (its header starts {header[:40]!r})")
    n = len(header.split(","))
    rows, lines = read_csv_rows(path, n)
    t = parse_timestamps(path, rows, lines)
    a = parse_floats(path, rows, lines, slice(1, 11))
    return t, a[:, 0:3].copy(), a[:, 6:10].copy()


def read_kitti_poses(path: Path) -> Trajectory:
    """KITTI poses (3x4 per line); times from ``times.txt`` beside the file when it has one
    per pose, else pose ``i`` at ``i`` seconds (two such files then pair by index)."""
    from svains.geometry.rotation import rotmat_to_quat

    try:
        a = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise DatasetError(f"{path}: malformed KITTI poses: {exc}") from None
    if a.shape[1] != 12 or not np.all(np.isfinite(a)):
        raise DatasetError(f"{path}: KITTI poses need 12 finite numbers per line")
    T = a.reshape(-1, 3, 4)
    times = path.parent / "times.txt"
    t_s = np.loadtxt(times, ndmin=1) if times.is_file() else None
    if t_s is None or t_s.size != T.shape[0]:
        log.info("%s: no times.txt with %d rows; pose i is at i seconds", path, T.shape[0])
        t_ns = np.arange(T.shape[0], dtype=np.int64) * 1_000_000_000
    else:
        t_ns = np.round(t_s * 1e9).astype(np.int64)
    return t_ns, T[:, :, 3].copy(), rotmat_to_quat(T[:, :, :3])


def read_trajectory(
    path: Path | str, fmt: TrajectoryFormat | None = None, topic: str | None = None
) -> Trajectory:
    """(t_ns (N,), p (N, 3) m, q_wxyz (N, 4)) of ``path`` in ``fmt`` (auto-detected if None);
    ``topic`` picks a bag's pose topic (else its only pose topic)."""
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt not in FORMATS:
        raise DatasetError(f"unknown trajectory format {fmt!r} (one of {', '.join(FORMATS)})")
    if fmt == "tum":
        return read_tum(p)
    if fmt == "euroc":
        return read_euroc_csv(p)
    if fmt == "states":
        return read_states_csv(p)
    if fmt == "kitti":
        return read_kitti_poses(p)
    if fmt == "bag":
        from svains.datasets.rosbag import read_bag

        ds = read_bag(p, {"gt": topic}, roles=("gt",))
    else:
        gt = _asl_groundtruth(p)
        if gt is not None:
            return gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz
        from svains.datasets.loader import load_dataset

        ds = load_dataset(p)
    if ds.groundtruth is None:
        what = "bag has no pose topic" if fmt == "bag" else "data set has no ground truth"
        raise DatasetError(f"{p}: {what}")
    return ds.groundtruth.t_ns, ds.groundtruth.p_W_B, ds.groundtruth.q_W_B_wxyz


def _asl_groundtruth(p: Path) -> GroundTruth | None:
    """An ASL folder's ground truth read alone (None for other layouts): a reference needs
    no sensor calibration (a Kalibr-calibrated folder without ``sensor.yaml`` files was refused
    by ``evaluate`` for its IMU's: a user's probe)."""
    from svains.datasets.asl_reader import find_mav0, read_groundtruth
    from svains.datasets.tumvi import is_tumvi

    if not p.is_dir() or is_tumvi(p):
        return None
    mav0 = find_mav0(p)
    folder = None if mav0 is None else mav0 / "state_groundtruth_estimate0"
    return read_groundtruth(folder) if folder is not None and folder.is_dir() else None
