"""A GPS faster than 1-2 Hz: does the in-flight start and the filter stay consistent? Plain
script (not a timed test).

Receivers give fixes at 5-50 Hz as readily as at 1 Hz. Per rate and seed, a simulated 20 s
village flight (``SimConfig(duration_s=20, seed=seed)``, feature-level, magnetometer and
sonar, GPS without outages at ``gps.rate_hz`` = the rate, its white noise as declared) runs
through ``svains.evaluation.run.run_method`` with an in-flight start (``--init gps``).
Prints per rate and method the ATE and mean NEES (9 dof) of each seed, their means, the
start's attitude error [deg], the bias-step test's alarms (``recovery.bias_shifts``) and
the largest lag-one correlation of the GPS position innovations
(``report.json`` ``gps_whiteness``: above 0.5 it is warned).

    python bench/gps_rate.py [--rates 1,10,20,50] [--seeds 0-2] [--methods ins]
                             [--duration-s 20] [--correlation-s TAU] [--undeclared]

``--correlation-s`` makes the positions' noise a first-order Gauss-Markov process with that
time constant (``gps.position_correlation_s``: a real receiver's noise wanders over seconds),
declared in ``gps0/sensor.yaml`` unless ``--undeclared`` (the calibration then says white, as
a user who knows only the receiver's σ would write it).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from faults import parse_seeds  # bench/faults.py: "0-7", "0,1,5" or "3"

from svains.datasets import load_dataset
from svains.evaluation.run import run_method
from svains.geometry.rotation import quat_box_minus
from svains.navigation.options import InitOptions, RunOptions
from svains.replay.groundtruth import interpolate_groundtruth
from svains.sim import SimConfig, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", default="1,10,20,50", help="GPS rates [Hz, comma-separated]")
    ap.add_argument("--seeds", type=parse_seeds, default=[0, 1, 2])
    ap.add_argument("--methods", default="ins")
    ap.add_argument("--duration-s", type=float, default=20.0)
    ap.add_argument("--correlation-s", type=float, default=0.0,
                    help="the positions' noise correlation time [s] (0: white)")
    ap.add_argument("--undeclared", action="store_true",
                    help="the calibration leaves the correlation out")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    rates = [float(r) for r in args.rates.split(",") if r.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    options = RunOptions(init=InitOptions(mode="gps"))
    print("| GPS rate | method | ATE m per seed | NEES per seed | mean ATE | mean NEES "
          "| start attitude error deg | bias alarms | innovations' lag-one correlation |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for rate in rates:
            data = []
            for seed in args.seeds:
                cfg = SimConfig(duration_s=args.duration_s, seed=seed)
                gps = replace(cfg.gps, rate_hz=rate, outages=[],
                              position_correlation_s=args.correlation_s)
                cfg = replace(cfg, gps=gps, camera=replace(cfg.camera, render_images=False))
                ds = load_dataset(simulate(cfg, Path(tmp) / f"r{rate:g}_s{seed}"))
                if args.undeclared and ds.gps_calib is not None:
                    ds.gps_calib = replace(ds.gps_calib, position_correlation_s=0.0)
                data.append(ds)
            for method in methods:
                ate, nees, start, alarms, rho = [], [], [], [], []
                for ds in data:
                    res = run_method(ds, method, options)
                    ate.append(res.report["ate_rmse_m"])
                    nees.append(res.report["nees_mean"])
                    _, _, _, q = interpolate_groundtruth(ds.groundtruth, res.t_ns[:1])
                    err = quat_box_minus(res.x[0, 6:10], q[0])
                    start.append(float(np.degrees(np.linalg.norm(err))))
                    alarms.append(res.report["recovery"]["bias_shifts"])
                    white = res.report.get("gps_whiteness") or {}
                    rho.append(white.get("lag1_correlation_max"))
                print(f"| {rate:g} Hz | {method} | {' / '.join(f'{a:.3f}' for a in ate)} "
                      f"| {' / '.join(f'{n:.1f}' for n in nees)} | {np.mean(ate):.3f} "
                      f"| {np.mean(nees):.2f} | {' / '.join(f'{a:.1f}' for a in start)} "
                      f"| {' / '.join(str(a) for a in alarms)} "
                      f"| {' / '.join('-' if r is None else f'{r:.2f}' for r in rho)} |")


if __name__ == "__main__":
    main()
