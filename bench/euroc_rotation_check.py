"""EuRoC micro (``../shared/data/euroc_v101_micro``): is the MAV really static between frames?

For every stereo frame pair the front end's estimated rotation is printed next to two independent
references: the ground-truth (Vicon) relative rotation and the bias-corrected gyro integrated
between the two image timestamps (bias: the ground truth's ``bg_B`` at that time). Frames whose
estimate exceeds ``0.08`` deg are listed, then the maxima. This is the evidence behind the
front-end issue's "rotation < 0.1 deg" line: where the estimate is near 0.1 deg, the gyro and the
ground truth say the MAV turned by as much.

Usage: ``python bench/euroc_rotation_check.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset, stereo_pairs
from svains.frontend.run import run_frontend
from svains.geometry.rotation import so3_exp, so3_log

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"


def gyro_rotation_deg(
    t_ns: np.ndarray, gyro: np.ndarray, bias: np.ndarray, t0: int, t1: int
) -> float:
    """Angle (deg) of the rotation integrated from bias-corrected gyro samples in [t0, t1)."""
    m = (t_ns >= t0) & (t_ns < t1)
    idx = np.flatnonzero(m)
    R = np.eye(3)
    for i in idx:
        dt = (min(int(t_ns[i + 1]) if i + 1 < t_ns.size else t1, t1) - int(t_ns[i])) * 1e-9
        R = R @ so3_exp((gyro[i] - bias) * dt)
    return float(np.degrees(np.linalg.norm(so3_log(R))))


def main() -> int:
    if not DATA.is_dir():
        print(f"missing data: {DATA}")
        return 1
    ds = load_dataset(DATA)
    pairs = stereo_pairs(ds)
    run = run_frontend(ds, pairs)
    assert ds.imu is not None and ds.groundtruth is not None
    gt = ds.groundtruth
    rows = []
    for r in run.records[1:]:
        if r.egomotion is None:
            continue
        t0, t1 = int(pairs[0][r.index - 1]), int(pairs[0][r.index])
        bias = gt.bg_B[np.searchsorted(gt.t_ns, t0).clip(0, gt.t_ns.size - 1)]
        g = gyro_rotation_deg(ds.imu.t_ns, ds.imu.gyro_B, bias, t0, t1)
        assert run.T_W_C_gt is not None
        dR = run.T_W_C_gt[r.index - 1][:3, :3].T @ run.T_W_C_gt[r.index][:3, :3]
        gt_deg = float(np.degrees(np.linalg.norm(so3_log(dR))))
        rows.append((r.index, r.rotation_deg, r.rotation_error_deg, g, gt_deg))
    print("frame  estimated_deg  groundtruth_deg  gyro_integrated_deg  error_vs_groundtruth_deg")
    for idx, est, err, g, gt_deg in rows:
        if est > 0.08:
            print(f"{idx:5d}  {est:13.4f}  {gt_deg:15.4f}  {g:19.4f}  {err:24.4f}")
    est = np.array([r[1] for r in rows])
    err = np.array([r[2] for r in rows])
    gyr = np.array([r[3] for r in rows])
    print(f"max estimated {est.max():.4f} deg (frame {rows[int(est.argmax())][0]}), "
          f"frames >= 0.1 deg: {int((est >= 0.1).sum())} of {est.size}")  # fmt: skip
    print(f"max error against ground truth {err.max():.4f} deg, median {np.median(err):.4f}")
    print(f"max gyro-integrated rotation {gyr.max():.4f} deg; at the max-estimate frame "
          f"{gyr[int(est.argmax())]:.4f} deg")  # fmt: skip
    return 0


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        sys.exit(main())
