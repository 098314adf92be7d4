"""GPS outages on a real drive: in-flight start from GPS (no magnetometer: heading from the GPS
course), GPS fixes dropped inside the given windows, ``ins`` and the vision methods compared by
their largest position error inside each outage.

Until ``--gps-outage START:DURATION`` exists on the command line, this script drops the fixes
itself (a copy of the data set in memory; the files are not touched).

    python bench/kitti_outages.py [DATASET] [--outage 10:10 --outage 25:10] [--methods ins,3d]
                                  [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace

import numpy as np

from svains.cli.run_config import build_config
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset, GpsStream
from svains.evaluation.compare import run_methods


def without_fixes(ds: Dataset, windows_s: list[tuple[float, float]]) -> Dataset:
    """``ds`` with the GPS fixes inside ``[start, start + duration)`` (s after the first IMU
    sample) removed."""
    assert ds.gps is not None and ds.imu is not None
    t0 = int(ds.imu.t_ns[0])
    t = np.asarray(ds.gps.t_ns, np.int64)
    keep = np.ones(t.size, bool)
    for start, dur in windows_s:
        a, b = t0 + int(start * 1e9), t0 + int((start + dur) * 1e9)
        keep &= ~((t >= a) & (t < b))
    g = ds.gps
    return replace(ds, gps=GpsStream(t[keep], g.p_W_G[keep], g.v_W_G[keep]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="../shared/data/kitti_raw_0926_41s")
    ap.add_argument("--outage", action="append", default=[], help="START:DURATION seconds")
    ap.add_argument("--methods", default="ins,3d")
    ap.add_argument("--set", action="append", default=[], help="vision option KEY=VALUE")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    windows = [tuple(float(v) for v in o.split(":")) for o in args.outage] or [(10, 10), (25, 10)]
    ds = without_fixes(load_dataset(args.dataset), windows)  # type: ignore[arg-type]
    opts = build_config(None, args.set, {"init.mode": "gps", "vision.source": "images",
                                         "vision.rotation": "clone"})
    mo = opts.vision
    res = run_methods(ds, tuple(args.methods.split(",")), opts, None)
    print(f"outages {windows} s, in-flight GPS start, options {mo}")
    for m, r in res.items():
        rep = r.report
        errs = rep.get("outage_max_error_m")
        cells = "-" if errs is None else ", ".join(f"{e:.2f}" for e in errs)
        print(f"{m:4s} max error in each outage [m]: {cells}   heading: "
              f"{rep.get('init', {}).get('heading')}   ATE {rep.get('ate_m', float('nan')):.3f} m")


if __name__ == "__main__":
    main()
