"""Where a run's position error lies: horizontal or vertical, inside and outside GPS outages.

Plain script. For each run folder, reads ``trajectory.tum`` (and ``trajectory_smoothed.tum``
when there), interpolates the data set's ground truth at each pose (no alignment: a GPS-aided
run is already in the reference's frame) and prints the largest 3-D, horizontal and vertical
error inside each window, and the largest horizontal and vertical error outside all windows
(where GPS is fused). Windows are ``START:DURATION`` in s after the first IMU sample, as
``svains run --gps-outage`` takes them.

``--reference-velocity`` adds a second yardstick inside each window: the reference's own
velocity integrated (trapezoid over its samples) and tied to the reference position at the
window's two ends, the best an estimator that knew the true velocity and the fixes around an
outage could do. It prints how far the reference's positions are from that path (the
reference's own inconsistency: on KITTI raw the OXTS height and vertical velocity disagree) and
each run's largest error against it.

    python bench/height_split.py ../shared/data/kitti_raw_0926_41s R3D RINS \\
        --window 10:10 --window 25:10 [--reference-velocity]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets import load_dataset
from svains.datasets.trajectory import read_tum
from svains.datasets.types import GroundTruth
from svains.replay.groundtruth import interpolate_groundtruth

F64 = NDArray[np.float64]


def velocity_path(gt: GroundTruth, t_ns: NDArray[np.int64], a_ns: int, b_ns: int) -> F64:
    """Positions (N, 3) at ``t_ns`` (inside ``[a_ns, b_ns]``) of the reference's velocity
    integrated by the trapezoid rule, plus the linear correction that ties the path to the
    reference position at ``a_ns`` and ``b_ns``."""
    t_s = (gt.t_ns - gt.t_ns[0]) / 1e9
    dp = np.diff(t_s)[:, None] * 0.5 * (gt.v_W_B[1:] + gt.v_W_B[:-1])
    integral = np.vstack([np.zeros(3), np.cumsum(dp, axis=0)])

    def at(t: NDArray[np.int64], y: F64) -> F64:
        ts = (np.asarray(t, np.int64) - gt.t_ns[0]) / 1e9
        return np.stack([np.interp(ts, t_s, y[:, i]) for i in range(3)], axis=1)

    ends = np.array([a_ns, b_ns], np.int64)
    p_ends, i_ends = at(ends, gt.p_W_B), at(ends, integral)
    frac = ((np.asarray(t_ns, np.int64) - a_ns) / (b_ns - a_ns))[:, None]
    drift = (p_ends[1] - p_ends[0]) - (i_ends[1] - i_ends[0])
    return at(t_ns, integral) - i_ends[0] + p_ends[0] + frac * drift


def split(e: F64) -> str:
    """Largest 3-D / horizontal / vertical norm of errors ``e`` (N, 3)."""
    return (f"{np.linalg.norm(e, axis=1).max():.2f} / {np.linalg.norm(e[:, :2], axis=1).max():.2f}"
            f" / {np.abs(e[:, 2]).max():.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("runs", type=Path, nargs="+", help="svains run output folders")
    ap.add_argument("--window", action="append", default=[], metavar="START:DURATION")
    ap.add_argument("--reference-velocity", action="store_true",
                    help="also compare against the reference's own velocity, integrated")
    args = ap.parse_args()
    ds = load_dataset(args.dataset)
    if ds.groundtruth is None or ds.imu is None:
        raise SystemExit(f"error: {args.dataset} has no ground truth or no IMU")
    gt = ds.groundtruth
    t0 = int(ds.imu.t_ns[0])
    windows = [tuple(float(v) for v in w.split(":")) for w in args.window]
    if args.reference_velocity:
        own = []
        for a, d in windows:
            a_ns, b_ns = t0 + round(a * 1e9), t0 + round((a + d) * 1e9)
            m = (gt.t_ns >= a_ns) & (gt.t_ns <= b_ns)
            own.append(f"{a:g}-{a + d:g} s: "
                       f"{split(gt.p_W_B[m] - velocity_path(gt, gt.t_ns[m], a_ns, b_ns))}")
        print("reference position against its own velocity, integrated and tied at each "
              "window's ends (3-D / horizontal / vertical max [m]): " + "; ".join(own))
    print("| run | trajectory | " + " | ".join(
        f"{a:g}-{a + d:g} s: 3-D / horizontal / vertical max [m]" for a, d in windows
    ) + " | outside: horizontal / vertical max [m] |")  # fmt: skip
    print("|---|---|" + "---|" * (len(windows) + 1))
    for run in args.runs:
        for name in ("trajectory.tum", "trajectory_smoothed.tum"):
            if not (run / name).is_file():
                continue
            t_ns, p, _ = read_tum(run / name)
            inside, ref, _, _ = interpolate_groundtruth(gt, t_ns)
            t_ns, e = t_ns[inside], p[inside] - ref
            t_s = (t_ns - t0) / 1e9
            cells, outside = [], np.ones(t_s.size, bool)
            for a, d in windows:
                m = (t_s >= a) & (t_s <= a + d)
                outside &= ~m
                cell = split(e[m])
                if args.reference_velocity:
                    a_ns, b_ns = t0 + round(a * 1e9), t0 + round((a + d) * 1e9)
                    path = velocity_path(gt, t_ns[m], a_ns, b_ns)
                    cell += f" (own velocity: {split(p[inside][m] - path)})"
                cells.append(cell)
            cells.append(f"{np.linalg.norm(e[outside, :2], axis=1).max():.2f} / "
                         f"{np.abs(e[outside, 2]).max():.2f}")  # fmt: skip
            print(f"| {run.name} | {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
