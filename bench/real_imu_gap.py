"""An IMU gap cut into a real data set (in memory): how a method fares across it.

Plain script (not a timed test). Loads the data set, removes the IMU samples of
``[start + at, start + at + gap)`` and runs the method from the ground truth, GPS and
magnetometer off, vision from images, once per value of ``faults.gap_vision_two_view``
(the ``3d`` update across a gap), and prints the final error, ATE, NEES and how many gaps the
run saw. ``--clean`` also runs the data set as it is.

    python bench/real_imu_gap.py ../shared/data/kitti_raw_0926_41s --gap-s 5 --at 10
                                 [--method 3d] [--duration S] [--init static] [--clean]
                                 [--set KEY=VALUE ...]
    python bench/real_imu_gap.py ../shared/data/euroc_v101_micro --method ins --duration 10 \
                                 --init static --at 2 --clean    # issue 23's real-IMU gap
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import Dataset, ImuStream
from svains.evaluation.run import run_method
from svains.replay import resolve_config

S = 1_000_000_000


def with_gap(ds: Dataset, at_s: float, gap_s: float) -> Dataset:
    """``ds`` without the IMU samples of ``[t0 + at_s, t0 + at_s + gap_s)`` (t0 its first)."""
    assert ds.imu is not None
    t = ds.imu.t_ns
    t0 = int(t[0]) + round(at_s * S)
    keep = ~((t >= t0) & (t < t0 + round(gap_s * S)))
    return replace(ds, imu=ImuStream(t[keep], ds.imu.gyro_B[keep], ds.imu.accel_B[keep]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--gap-s", type=float, default=5.0)
    ap.add_argument("--at", type=float, default=10.0, help="gap start, s after the first sample")
    ap.add_argument("--method", default="3d")
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--init", default="groundtruth", help="groundtruth, static or gps")
    ap.add_argument("--clean", action="store_true", help="also run without the gap")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = ap.parse_args()
    switches = {"method": args.method, "init.mode": args.init, "use_gps": False,
                "use_mag": False, "vision.source": "images", "duration_s": args.duration}
    clean = load_dataset(args.dataset)
    runs = [("clean", clean, "true")] if args.clean else []
    gapped = with_gap(clean, args.at, args.gap_s)
    runs += [(f"gap {args.gap_s:g} s at {args.at:g} s", gapped, tv) for tv in ("true", "false")]
    print("| data | gap_vision_two_view | final error [%] | ATE [m] | NEES | IMU gaps | "
          "roll/pitch NEES |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, ds, tv in runs:
        config = build_config(None, [f"faults.gap_vision_two_view={tv}", *args.set], switches)
        rep = run_method(ds, None, resolve_config(ds, config)).report
        print(f"| {name} | {tv} | {rep['final_error_pct']:.3f} | {rep['ate_rmse_m']:.3f} | "
              f"{rep['nees_mean']:.1f} | {rep['imu_faults']['gaps']} | "
              f"{(rep.get('nees_blocks') or {}).get('roll_pitch', float('nan')):.2f} |", flush=True)


if __name__ == "__main__":
    main()
