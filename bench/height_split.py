"""Where a run's position error lies: horizontal or vertical, inside and outside GPS outages.

Plain script. For each run folder, reads ``trajectory.tum`` (and ``trajectory_smoothed.tum``
when there), interpolates the data set's ground truth at each pose (no alignment: a GPS-aided
run is already in the reference's frame) and prints the largest 3-D, horizontal and vertical
error inside each window, and the largest horizontal and vertical error outside all windows
(where GPS is fused). Windows are ``START:DURATION`` in s after the first IMU sample, as
``svains run --gps-outage`` takes them.

    python bench/height_split.py ../shared/data/kitti_raw_0926_41s R3D RINS \\
        --window 10:10 --window 25:10
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset
from svains.datasets.trajectory import read_tum
from svains.replay.groundtruth import interpolate_groundtruth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("runs", type=Path, nargs="+", help="svains run output folders")
    ap.add_argument("--window", action="append", default=[], metavar="START:DURATION")
    args = ap.parse_args()
    ds = load_dataset(args.dataset)
    if ds.groundtruth is None or ds.imu is None:
        raise SystemExit(f"error: {args.dataset} has no ground truth or no IMU")
    gt = ds.groundtruth
    t0 = int(ds.imu.t_ns[0])
    windows = [tuple(float(v) for v in w.split(":")) for w in args.window]
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
                cells.append(f"{np.linalg.norm(e[m], axis=1).max():.2f} / "
                             f"{np.linalg.norm(e[m, :2], axis=1).max():.2f} / "
                             f"{np.abs(e[m, 2]).max():.2f}")  # fmt: skip
            cells.append(f"{np.linalg.norm(e[outside, :2], axis=1).max():.2f} / "
                         f"{np.abs(e[outside, 2]).max():.2f}")  # fmt: skip
            print(f"| {run.name} | {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
