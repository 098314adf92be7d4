"""Issue 27 on KITTI raw: is a camera-IMU time offset added to the image stamps recovered online?

``3d`` GPS-denied from the reference start (magnetometer off, images), as the README's KITTI
figures: on the data set as it is and with its image stamps moved by ``--shifts`` ms (through a
Kalibr camchain with that ``timeshift_cam_imu``, as ``svains run --calib`` does: the calibration
then says the offset is that value), each without and with ``vision.estimate_time_offset``.
Moving the stamps by +s moves the true offset relative to them by -s, so the filter's residual
(``time_offset_ms - time_offset_applied_ms``) should move by -s from the unshifted run's, and its
total estimate (``time_offset_ms``) stay where the unshifted run put it.

    python bench/kitti_time_offset.py [DATASET] [--shifts 30 -30] [--out DIR] [--set KEY=VALUE]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from svains.cli.run_config import build_config
from svains.datasets.kalibr import write_camchain
from svains.datasets.loader import load_dataset
from svains.evaluation.compare import trajectory_metrics
from svains.evaluation.run import run_method


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="../shared/data/kitti_raw_0926_41s")
    ap.add_argument("--shifts", type=float, nargs="*", default=[30.0, -30.0], help="ms")
    ap.add_argument("--out", type=Path, default=Path("kitti_time_offset"))
    ap.add_argument("--set", action="append", default=[], help="extra option KEY=VALUE")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    args.out.mkdir(parents=True, exist_ok=True)
    base = load_dataset(args.dataset)
    assert base.cam0 is not None and base.cam1 is not None
    T_B_I = base.imu_calib.T_B_S if base.imu_calib is not None else None
    switches = {"use_gps": False, "use_mag": False, "init.mode": "groundtruth",
                "vision.source": "images"}
    rows = []
    for shift_ms in [0.0, *args.shifts]:
        if shift_ms == 0.0:
            ds = base
        else:  # the cameras as they are, the stamps moved by the chain's timeshift
            chain = args.out / f"camchain_{shift_ms:+g}ms.yaml"
            write_camchain(chain, (base.cam0, base.cam1), T_B_I,
                           base.cam0.timeshift_cam_imu_s + shift_ms * 1e-3)
            ds = load_dataset(args.dataset, calib=chain)
        for estimate in (False, True):
            sets = [*args.set, f"vision.estimate_time_offset={str(estimate).lower()}"]
            opts = build_config(None, sets, switches)
            res = run_method(ds, "3d", opts)
            m = trajectory_metrics(res, ds, "3d", False)
            v = res.report["vision"]
            row = (f"shift {shift_ms:+5.1f} ms, estimate {'on ' if estimate else 'off'}: "
                   f"final error {m['final_error_pct_of_path']:.3f} % of the path, ATE "
                   f"{m['ate_m']:.3f} m, NEES {res.report.get('nees_mean', float('nan')):.1f}")
            if estimate:
                resid = v["time_offset_ms"] - v["time_offset_applied_ms"]
                row += (f"; offset {v['time_offset_ms']:+.2f} +- {v['time_offset_std_ms']:.2f} ms"
                        f" (applied {v['time_offset_applied_ms']:+.1f}, residual {resid:+.2f})")
            print(row, flush=True)
            rows.append(row)
    (args.out / "summary.txt").write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
