"""Does the paper's accuracy ordering (3d >= tc > lc > vo) hold? Ten seeds of the village flight.

Each seed: a GPS-denied, magnetometer-free village flight (feature-level simulation, stereo at
5 Hz), then ``vo``, ``lc``, ``tc`` and ``3d`` on it, as ``svains compare --no-gps --no-mag`` runs
them. Prints the ATE of every method per seed (posyaw alignment for all four, as ``svains
compare`` does for runs started from the true pose; VO's se3-aligned ATE is printed too), the
means, and how often each pair is ordered as the paper claims, by ATE and by final error.

    python bench/paper_ordering.py [--seeds 10] [--duration 60] [--rate 5] [--set KEY=VALUE ...]

``--set`` passes vision options (``rotation=clone``, ``min_disparity_px=5``, ...) to lc/tc/3d.
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
from svains.datasets.types import Dataset
from svains.evaluation.compare import align_to_groundtruth, run_methods
from svains.navigation.config_io import parse_setting
from svains.navigation.options import InitOptions, RunOptions, VisionOptions
from svains.sim import SimConfig, simulate

METHODS = ("vo", "lc", "tc", "3d")
# Pairs (better, worse) as the paper orders them.
PAPER_PAIRS = (("3d", "tc"), ("tc", "lc"), ("lc", "vo"), ("3d", "vo"), ("tc", "vo"))


def denied_village(seed: int, duration_s: float, rate_hz: float, root: Path) -> Dataset:
    """A GPS-denied-ready village flight (feature-level simulation, no images) written to
    ``root`` and loaded."""
    cfg = SimConfig()
    cfg = replace(cfg, seed=seed, duration_s=duration_s,
                  camera=replace(cfg.camera, rate_hz=rate_hz, render_images=False))  # fmt: skip
    return load_dataset(simulate(cfg, root))


def denied_options(**vision: object) -> RunOptions:
    """Run options of the GPS-denied, magnetometer-free runs (ground-truth start, features0,
    the default vision options), with extra ``vision`` options."""
    return RunOptions(
        model="biased", init=InitOptions(mode="groundtruth"), use_gps=False, use_mag=False,
        vision=VisionOptions(**{"source": "features", **vision}),  # type: ignore[arg-type]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=5.0, help="stereo rate [Hz]")
    ap.add_argument("--set", action="append", default=[], help="vision option KEY=VALUE")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    opts = denied_options(**dict(parse_setting(item) for item in args.set))
    ate = np.full((args.seeds, len(METHODS)), np.nan)
    final = np.full_like(ate, np.nan)
    vo_se3 = np.full(args.seeds, np.nan)
    nees_3d: list[float] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            ds = denied_village(seed, args.duration, args.rate, Path(tmp) / f"s{seed}")
            res = run_methods(ds, METHODS, opts, None)
            for j, m in enumerate(METHODS):
                ate[seed, j] = res[m].report.get("ate_m", np.nan)
                final[seed, j] = res[m].report.get("final_error_pct_of_path", np.nan)
            se3 = align_to_groundtruth(res["vo"], ds, "se3")
            vo_se3[seed] = se3.rmse if se3 is not None else np.nan
            nees = res["3d"].report.get("nees_mean", np.nan)
            row = "  ".join(f"{m} {ate[seed, j]:.3f}" for j, m in enumerate(METHODS))
            row += f"  (3d NEES {nees:.1f})"
            nees_3d.append(nees)
            print(f"seed {seed}: ATE [m]  {row}  (vo se3-aligned {vo_se3[seed]:.3f})", flush=True)
    print(f"\n{args.seeds} seeds, {args.duration:.0f} s GPS-denied village, "
          f"stereo {args.rate:g} Hz ({time.perf_counter() - t0:.0f} s)")
    print("method  ATE mean [m]  ATE median [m]  final error mean [% path]")
    for j, m in enumerate(METHODS):
        print(f"{m:6s}  {np.mean(ate[:, j]):12.3f}  {np.median(ate[:, j]):14.3f}  "
              f"{np.mean(final[:, j]):10.2f}")
    print(f"3d mean NEES (9 dof): {np.mean(nees_3d):.2f}")
    print(f"vo with se3 alignment (roll/pitch drift aligned away): ATE mean {np.mean(vo_se3):.3f}")
    idx = {m: j for j, m in enumerate(METHODS)}
    for name, val in (("ATE", ate), ("final error", final)):
        print(f"paper's pair (better > worse): seeds where it holds by {name}")
        for a, b in PAPER_PAIRS:
            tie = np.isclose(val[:, idx[a]], val[:, idx[b]], rtol=1e-6)
            wins = int(np.sum((val[:, idx[a]] < val[:, idx[b]]) & ~tie))
            ties = int(np.sum(tie))
            print(f"  {a} > {b}: {wins}/{args.seeds}" + (f" (equal in {ties})" if ties else ""))
    for name, val in (("ATE", ate), ("final error", final)):
        order = sorted(METHODS, key=lambda m: np.mean(val[:, idx[m]]))
        print(f"ordering by mean {name} (best first): " + " , ".join(order))


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        main()
