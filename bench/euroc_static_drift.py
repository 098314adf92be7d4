"""Position drift of a vision method over EuRoC micro's static start (real images, 4.6 s).

The MAV sits still while its 95 stereo pairs are recorded, so the estimate should not move:
prints the distance between the first and the last estimated position and the largest
excursion from the first (static start, GPS and magnetometer off).

    python bench/euroc_static_drift.py [--method 3d] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from svains.cli.run_config import build_config
from svains.datasets.loader import load_dataset
from svains.evaluation.run import run_method


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="../shared/data/euroc_v101_micro")
    ap.add_argument("--method", default="3d")
    ap.add_argument("--duration", type=float, default=4.6)
    ap.add_argument("--set", action="append", default=[], help="vision option KEY=VALUE")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    ds = load_dataset(args.dataset)
    opts = build_config(None, args.set, {"use_gps": False, "use_mag": False,
                                         "duration_s": args.duration, "vision.source": "images"})
    mo = opts.vision
    res = run_method(ds, args.method, opts)
    p = res.x[:, 0:3]
    span = (res.t_ns[-1] - res.t_ns[0]) * 1e-9
    drift = np.linalg.norm(p[-1] - p[0]) * 1e3
    excursion = np.max(np.linalg.norm(p - p[0], axis=1)) * 1e3
    print(f"{args.method} {mo}: drift {drift:.2f} mm, largest excursion {excursion:.2f} mm over "
          f"{span:.2f} s")


if __name__ == "__main__":
    main()
