"""The in-flight start from stereo and the IMU (``--init vision``) against a start from the true
state: the start's own errors and the run's, GPS-denied.

Part 1, the simulator's village (30 s, features0 at the default rate, the paper's vibrating
IMU, moving from the start), seeds 0-7: the start's tilt (deg) and body-velocity (m/s) errors
against the ground truth, and the `3d` run's ATE (se3) and NEES from either start. Part 2,
KITTI raw (``--images``, in motion from its first frame): ATE, drift over 100 m.

    python bench/vision_start.py [--seeds 0-7] [--window 2]
        [--kitti ../shared/data/kitti_raw_0926_41s]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from faults import parse_seeds

from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.run import run_method
from svains.geometry.rotation import quat_to_rotmat
from svains.navigation.options import InitOptions, RunConfig
from svains.replay.groundtruth import interpolate_groundtruth


def start_errors(ds: Dataset, config: RunConfig) -> tuple[float, float, dict]:
    """Tilt (deg) and body-velocity error norm (m/s) of the vision start (a run's first logged
    state is its start), and its info."""
    res = run_method(ds, config.method, replace(config, duration_s=1.0))
    assert ds.groundtruth is not None
    _, _, v, q = interpolate_groundtruth(ds.groundtruth, res.t_ns[:1])
    R_gt, R_est = quat_to_rotmat(q[0]), quat_to_rotmat(res.x[0, 6:10])
    up = np.array([0.0, 0.0, 1.0])
    tilt = float(np.degrees(np.arccos(np.clip((R_gt.T @ up) @ (R_est.T @ up), -1.0, 1.0))))
    dv = float(np.linalg.norm(R_gt.T @ v[0] - R_est.T @ res.x[0, 3:6]))
    return tilt, dv, res.report["init"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-7")
    ap.add_argument("--window", type=float, default=2.0, help="init.vision_window_s [s]")
    ap.add_argument("--kitti", default=None, help="KITTI raw data set (part 2)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    from svains.sim import SimConfig, simulate

    t0 = time.perf_counter()
    init = InitOptions(mode="vision", vision_window_s=args.window)
    base = RunConfig(method="3d", use_gps=False)
    print("| seed | start tilt error [deg] (its std) | start velocity error [m/s] | gravity "
          "fitted [m/s²] | `3d` ATE from the truth / vision [m] | NEES from the truth / vision |")
    print("|---|---|---|---|---|---|")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in parse_seeds(args.seeds):
            cfg = SimConfig(duration_s=30.0, seed=seed)
            cfg.camera.render_images = False
            cfg.gps.outages = []
            ds = load_dataset(simulate(cfg, Path(tmp) / f"s{seed}"))
            tilt, dv, info = start_errors(ds, replace(base, init=init))
            truth = run_method(ds, "3d", replace(base, init=InitOptions(mode="groundtruth")))
            vision = run_method(ds, "3d", replace(base, init=init))
            a, b = truth.report, vision.report
            rows.append((tilt, dv, a["ate_rmse_m"], b["ate_rmse_m"], a["nees_mean"],
                         b["nees_mean"]))
            print(f"| {seed} | {tilt:.3f} ({info['tilt_std_deg']:.2f}) | {dv:.3f} | "
                  f"{info['gravity_fit_mps2']:.3f} | {a['ate_rmse_m']:.3f} / "
                  f"{b['ate_rmse_m']:.3f} | "
                  f"{a['nees_mean']:.2f} / {b['nees_mean']:.2f} |", flush=True)
    r = np.array(rows)
    print(f"| mean | {r[:, 0].mean():.3f} | {r[:, 1].mean():.3f} | - | {r[:, 2].mean():.4f} / "
          f"{r[:, 3].mean():.4f} | {r[:, 4].mean():.2f} / {r[:, 5].mean():.2f} |")
    if args.kitti:
        ds = load_dataset(Path(args.kitti))
        kb = RunConfig(method="3d", use_gps=False, use_mag=False)
        kb = replace(kb, vision=replace(kb.vision, source="images"))
        tilt, dv, info = start_errors(ds, replace(kb, init=init))
        truth = run_method(ds, "3d", replace(kb, init=InitOptions(mode="groundtruth"))).report
        vision = run_method(ds, "3d", replace(kb, init=init)).report
        print(f"\nKITTI raw `3d` GPS-denied from images: start tilt error {tilt:.3f}° (std "
              f"{info['tilt_std_deg']:.2f}°), velocity error {dv:.3f} m/s, gravity fitted "
              f"{info['gravity_fit_mps2']:.3f} m/s² ({info['frames']} frames); ATE from the truth "
              f"{truth['ate_rmse_m']:.3f} m, from vision {vision['ate_rmse_m']:.3f} m; drift over "
              f"100 m {truth['drift_100m_pct']:.3f} / {vision['drift_100m_pct']:.3f} %")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
