"""Does the paper's accuracy ordering (3d >= tc > lc > vo) hold? Ten seeds of the village flight.

Each seed: a GPS-denied, magnetometer-free village flight (feature-level simulation, stereo at
5 Hz), then ``vo``, ``lc``, ``tc`` and ``3d`` on it, as ``svains compare --no-gps --no-mag`` runs
them. Prints the ATE of every method per seed (posyaw alignment for the filters, se3 for VO, as
``svains compare``), the means, and how often each pair is ordered as the paper claims.

    python bench/paper_ordering.py [--seeds 10] [--duration 60] [--rate 5]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from svains.datasets.loader import load_dataset
from svains.evaluation.compare import run_methods
from svains.navigation.options import InitOptions, RunOptions
from svains.sim import SimConfig, simulate

METHODS = ("vo", "lc", "tc", "3d")
# Pairs (better, worse) as the paper orders them.
PAPER_PAIRS = (("3d", "tc"), ("tc", "lc"), ("lc", "vo"), ("3d", "vo"), ("tc", "vo"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=5.0, help="stereo rate [Hz]")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    opts = RunOptions(
        model="biased", init=InitOptions(mode="groundtruth"), use_gps=False, use_mag=False,
        method_options={"source": "features", "rotation": "imu"},
    )
    ate = np.full((args.seeds, len(METHODS)), np.nan)
    final = np.full_like(ate, np.nan)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            cfg = SimConfig()
            cfg = replace(cfg, seed=seed, duration_s=args.duration,
                          camera=replace(cfg.camera, rate_hz=args.rate, render_images=False))
            ds = load_dataset(simulate(cfg, Path(tmp) / f"s{seed}"))
            res = run_methods(ds, METHODS, opts, None)
            for j, m in enumerate(METHODS):
                ate[seed, j] = res[m].report.get("ate_m", np.nan)
                final[seed, j] = res[m].report.get("final_error_pct_of_path", np.nan)
            row = "  ".join(f"{m} {ate[seed, j]:.3f}" for j, m in enumerate(METHODS))
            print(f"seed {seed}: ATE [m]  {row}", flush=True)
    print(f"\n{args.seeds} seeds, {args.duration:.0f} s GPS-denied village, "
          f"stereo {args.rate:g} Hz ({time.perf_counter() - t0:.0f} s)")
    print("method  ATE mean [m]  ATE median [m]  final error mean [% path]")
    for j, m in enumerate(METHODS):
        print(f"{m:6s}  {np.mean(ate[:, j]):12.3f}  {np.median(ate[:, j]):14.3f}  "
              f"{np.mean(final[:, j]):10.2f}")
    idx = {m: j for j, m in enumerate(METHODS)}
    print("paper's pair (better > worse): seeds where it holds by ATE")
    for a, b in PAPER_PAIRS:
        tie = np.isclose(ate[:, idx[a]], ate[:, idx[b]], rtol=1e-6)
        wins = int(np.sum((ate[:, idx[a]] < ate[:, idx[b]]) & ~tie))
        ties = int(np.sum(tie))
        print(f"  {a} > {b}: {wins}/{args.seeds}" + (f" (equal in {ties})" if ties else ""))
    order = sorted(METHODS, key=lambda m: np.mean(ate[:, idx[m]]))
    print("ordering by mean ATE (best first): " + " , ".join(order))


if __name__ == "__main__":
    main()
