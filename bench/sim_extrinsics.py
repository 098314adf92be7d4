"""Online camera-IMU rotation (``vision.estimate_extrinsics``) on the simulated village flight.

GPS-denied, magnetometer-free, feature-level simulation (stereo 5 Hz), started from the true
pose, as ``bench/specs/paper_ordering.yaml``. For each seed, ``3d`` and ``lc`` run with the
calibration as simulated (exact) and with both cameras' ``T_B_C`` turned by ``--tilt-deg``
(about the left camera's x and y axes: the kind of error KITTI's calibration chain shows),
each with and without the online estimate. Prints the position RMSE, final error (% of the path),
NEES mean (9 dof) and the estimated correction against the one applied. With ``--from-gps``,
the turned set's rotation is instead estimated by a ``3d`` run WITH GPS, applied
(``evaluation.extrinsics.corrected_calibration``), and ``3d`` runs GPS-denied with it.

    python bench/sim_extrinsics.py [--seeds 3] [--duration 60] [--tilt-deg 0.4] [--from-gps]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
from pathlib import Path

import numpy as np

from svains.cli.run_config import build_config
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.extrinsics import corrected_calibration, turn_cameras
from svains.evaluation.run import run_method
from svains.sim import SimConfig, simulate


def turned(ds: Dataset, phi_rad: np.ndarray) -> Dataset:
    """``ds`` whose calibration says the stereo rig sits turned by ``Exp(-phi)`` (cam0 axes,
    rigidly) from where it is: the correction the filter should find is ``phi``."""
    return turn_cameras(ds, -phi_rad)


def gps_calibrated(seed: int, exact: Dataset, wrong: Dataset, sets: list[str]) -> None:
    """Estimate the rotation with GPS on ``wrong``, apply it, run 3d GPS-denied; print all."""
    base = {"init.mode": "groundtruth", "use_mag": False, "vision.source": "features",
            "vision.rotation": "clone"}
    opts = build_config(None, [*sets, "vision.estimate_extrinsics=true"],
                        {**base, "use_gps": True})
    vis = run_method(wrong, "3d", opts).report["vision"]
    phi = np.array(vis["extrinsic_rotation_deg"])
    print(f"{seed:4d} with GPS: estimated {np.round(phi, 3).tolist()} deg, "
          f"std {np.round(vis['extrinsic_rotation_std_deg'], 3).tolist()}")
    denied = build_config(None, sets, {**base, "use_gps": False})
    for name, d in (("exact", exact), ("turned", wrong),
                    ("turned+gps-estimate", corrected_calibration(wrong, np.radians(phi)))):
        r = run_method(d, "3d", denied).report
        print(f"{seed:4d} 3d GPS-denied, {name:20s} RMSE {r['position_rmse_m']:.3f} m, final "
              f"{r['final_error_pct']:.2f} %, NEES {r['nees_mean']:.1f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--tilt-deg", type=float, default=0.4)
    ap.add_argument("--methods", default="3d,lc")
    ap.add_argument("--set", action="append", default=[], help="option KEY=VALUE")
    ap.add_argument("--from-gps", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    phi = np.radians([args.tilt_deg, -args.tilt_deg, 0.0])
    print(f"applied calibration error (correction to find): {np.degrees(phi)} deg")
    print("seed method calib      estimate  RMSE[m] final[%]  NEES   est.correction[deg]")
    for seed in range(args.seeds):
        with tempfile.TemporaryDirectory() as tmp:
            cfg = SimConfig.from_dict({"duration_s": args.duration, "seed": seed,
                                       "camera": {"rate_hz": 5.0, "render_images": False}})
            ds0 = load_dataset(simulate(cfg, Path(tmp) / "data"))
            if args.from_gps:
                gps_calibrated(seed, ds0, turned(ds0, phi), args.set)
                continue
            for calib, ds in (("exact", ds0), ("turned", turned(ds0, phi))):
                for method in args.methods.split(","):
                    for est in (False, True):
                        sets = [*args.set, f"vision.estimate_extrinsics={est}"]
                        opts = build_config(None, sets, {
                            "init.mode": "groundtruth", "use_gps": False, "use_mag": False,
                            "vision.source": "features", "vision.rotation": "clone"})
                        r = run_method(ds, method, opts).report
                        vis = r.get("vision", {})
                        ext = vis.get("extrinsic_rotation_deg")
                        ext_s = "-" if ext is None else (
                            f"{np.round(ext, 3).tolist()} "
                            f"std {np.round(vis['extrinsic_rotation_std_deg'], 3).tolist()}")
                        print(f"{seed:4d} {method:6s} {calib:8s} {est!s:9s} "
                              f"{r['position_rmse_m']:6.3f}  {r['final_error_pct']:7.2f}  "
                              f"{r['nees_mean']:5.1f}  {ext_s}", flush=True)


if __name__ == "__main__":
    main()
