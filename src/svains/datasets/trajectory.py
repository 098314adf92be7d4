"""TUM trajectory files: ``t x y z qx qy qz qw`` per line, ``t`` in seconds, ``#`` comments.

Timestamps are converted between int64 ns and decimal seconds exactly (no float rounding), and
quaternions between our scalar-first ``q_wxyz`` and TUM's ``qx qy qz qw`` at this edge only.
"""

from __future__ import annotations

import logging
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.datasets._textio import read_text
from svains.datasets.types import GroundTruth
from svains.datasets.validate import QUATERNION_NORM_TOL
from svains.errors import DatasetError
from svains.sensors.units import seconds_unit_hint

log = logging.getLogger(__name__)

TUM_HEADER = "timestamp[s] tx ty tz qx qy qz qw"
# Below this norm a quaternion is read as no rotation at all (zeros), not a scaled one.
MIN_QUATERNION_NORM = 0.1


def ns_to_seconds_text(t_ns: int) -> str:
    """Exact decimal text of ``t_ns`` nanoseconds in seconds (e.g. ``1403715273.262142976``)."""
    sign = "-" if t_ns < 0 else ""
    s, ns = divmod(abs(int(t_ns)), 1_000_000_000)
    return f"{sign}{s}.{ns:09d}"


def seconds_text_to_ns(text: str) -> int:
    """Seconds as decimal text to int ns, exact up to ns (rounded half-even beyond)."""
    return int((Decimal(text) * 1_000_000_000).to_integral_value())


def write_tum(
    path: Path | str,
    t_ns: ArrayLike,
    p_W_B: ArrayLike,
    q_W_B_wxyz: ArrayLike,
    comment: str | None = None,
) -> Path:
    """Write a TUM file: ``t_ns`` (N,) int64, ``p_W_B`` (N, 3) m, ``q_W_B_wxyz`` (N, 4)."""
    path = Path(path)
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    p = np.asarray(p_W_B, dtype=float).reshape(-1, 3)
    q = np.asarray(q_W_B_wxyz, dtype=float).reshape(-1, 4)
    if not (t.size == p.shape[0] == q.shape[0]):
        raise ValueError(f"lengths differ: t {t.size}, p {p.shape[0]}, q {q.shape[0]}")
    cols = np.concatenate([p, q[:, 1:], q[:, :1]], axis=1).tolist()
    lines = [f"# {TUM_HEADER}"]
    if comment:
        lines += [f"# {c}" for c in comment.splitlines()]
    lines += [
        ns_to_seconds_text(ti) + " " + " ".join(repr(v) for v in row)
        for ti, row in zip(t.tolist(), cols, strict=True)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def read_tum(
    path: Path | str,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Read a TUM file: (``t_ns`` (N,) int64, ``p`` (N, 3) m, ``q_wxyz`` (N, 4)).

    Fields may be separated by spaces or commas. Errors name the file and line: wrong field
    count, a bad number, NaN, non-increasing time, or an empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"missing file: {path}")
    t: list[int] = []
    rows: list[list[float]] = []
    lines: list[int] = []
    for k, raw in enumerate(read_text(path).splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise DatasetError(
                f"{path}:{k}: malformed TUM row, expected 8 fields (t x y z qx qy qz qw), "
                f"got {len(fields)}"
            )
        try:
            t.append(seconds_text_to_ns(fields[0]))
            rows.append([float(f) for f in fields[1:]])
        except (ValueError, InvalidOperation, OverflowError):
            raise DatasetError(f"{path}:{k}: malformed number in {line[:80]!r}") from None
        if not -(2**63) <= t[-1] < 2**63:
            raise DatasetError(f"{path}:{k}: time {fields[0]} s is outside the int64 ns range"
                               f"{seconds_unit_hint(float(fields[0]))}")
        lines.append(k)
    if not rows:
        raise DatasetError(f"{path}: no poses in TUM file")
    a = np.array(rows, dtype=float)
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise DatasetError(f"{path}:{lines[int(bad[0])]}: NaN or infinite value")
    t_ns = np.array(t, dtype=np.int64)
    d = np.diff(t_ns)
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0]) + 1
        kind = "duplicate" if d[i - 1] == 0 else "non-increasing"
        raise DatasetError(f"{path}:{lines[i]}: {kind} timestamp")
    q_wxyz = np.concatenate([a[:, 6:7], a[:, 3:6]], axis=1)
    norm = np.linalg.norm(q_wxyz, axis=1)
    if np.any(norm < MIN_QUATERNION_NORM):
        i = int(np.flatnonzero(norm < MIN_QUATERNION_NORM)[0])
        raise DatasetError(f"{path}:{lines[i]}: quaternion norm {norm[i]:.4g}: no rotation")
    off = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOL)
    if off.size:
        # Rounded or scaled quaternions still name one rotation; evo (the oracle) reads them
        # the same way, normalised.
        i = int(off[np.argmax(np.abs(norm[off] - 1.0))])
        log.warning("%s: %d quaternion(s) off unit norm by more than %g (line %d: %.4g): "
                    "normalised", path, off.size, QUATERNION_NORM_TOL, lines[i], norm[i])
        q_wxyz[off] /= norm[off, None]  # the rest as written: a round trip stays exact
    return t_ns, a[:, 0:3].copy(), q_wxyz


def write_groundtruth_tum(path: Path | str, gt: GroundTruth) -> Path:
    """Write a data set's ground truth (body frame) as a TUM file."""
    return write_tum(path, gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz, comment="ground truth, body frame")


def groundtruth_from_poses(
    t_ns: NDArray[np.int64], p_W_B: NDArray[np.float64], q_W_B_wxyz: NDArray[np.float64]
) -> GroundTruth:
    """Pose-only ground truth (mocap, bag poses): velocity ``v_W_B`` by central differences of
    the positions, biases zero (unknown). ``q_W_B_wxyz`` is normalised."""
    t = np.asarray(t_ns, np.int64)
    p = np.asarray(p_W_B, float).reshape(-1, 3)
    q = np.asarray(q_W_B_wxyz, float).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    v = np.gradient(p, (t - t[0]) * 1e-9, axis=0) if t.size > 1 else np.zeros_like(p)
    z = np.zeros_like(p)
    return GroundTruth(t_ns=t, p_W_B=p, q_W_B_wxyz=q, v_W_B=v, bg_B=z, ba_B=z.copy())
