"""INS filter figures: IMU steps per second, and the simulated village flight over many seeds.

Plain script (not a timed test); the machine's load at the time changes the timing figures.

    python bench/bench_filter.py                 # throughput only (EuRoC V1_01 IMU, 145 s)
    python bench/bench_filter.py --village 20    # + village flight, GPS with four 10 s outages,
                                                 #   20 seeds: RMSE, outage growth, 3σ, NEES
    python bench/bench_filter.py --euroc         # + EuRoC IMU: drift per 5 s window from ground
                                                 #   truth (both models), static-start gyro bias
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from svains.datasets import load_dataset
from svains.evaluation.run import run_method
from svains.models.imu import ImuChunk
from svains.models.state import BIASED
from svains.navigation.init import initialise
from svains.navigation.ins import InsFilter
from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions, RunOptions
from svains.replay.groundtruth import nees_series
from svains.replay.replay import history_from_dataset, rig_from_dataset

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"
TARGET = 20_000


def bench_predict(ds, steps: int, repeats: int = 200) -> tuple[float, float]:
    """Wall and CPU seconds per UKF predict over ``steps`` IMU steps (biased model, 37 points)."""
    init = initialise(ds, BIASED, InitOptions(mode="groundtruth"))
    ins = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), BIASED, init,
                    FilterOptions(max_predict_steps=steps), NoiseOptions())
    k = int(np.searchsorted(ins.t_imu, init.t_ns))
    sl = slice(k, k + steps + 1)
    chunk = ImuChunk(
        np.diff(ins.t_imu[sl]) * 1e-9, ins.gyro_B[sl], ins.accel_B[sl], ins.alpha_B[sl]
    )
    Q = ins._noise(int(ins.t_imu[sl][-1] - ins.t_imu[sl][0]))
    x0, P0 = ins.ukf.x.copy(), ins.ukf.P.copy()
    w, c = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        ins.ukf.x, ins.ukf.P = x0, P0
        ins.ukf.predict(ins.model, chunk, 0.0, Q)
    return (time.perf_counter() - w) / repeats, (time.process_time() - c) / repeats


def throughput() -> float:
    ds = load_dataset(DATA)
    print("predict alone (biased model, 37 sigma points, preintegrated chunk):")
    for steps in (1, 10, 20, 40):
        wall, cpu = bench_predict(ds, steps)
        print(
            f"  chunk {steps:2d} IMU steps: {wall * 1e6:7.0f} us wall, {cpu * 1e6:7.0f} us CPU"
            f" per predict = {steps / wall:7.0f} steps/s wall, {steps / cpu:7.0f} CPU"
        )
    print(f"whole INS on the EuRoC V1_01 IMU ({DATA.name}, ground-truth start, no aiding):")
    best = 0.0
    for model in ("biased", "paper"):
        for steps, period in ((10, 0.05), (20, 0.1), (40, 0.2)):
            opts = RunOptions(
                model=model,
                init=InitOptions(mode="groundtruth"),
                filter=FilterOptions(max_predict_steps=steps),
                output_period_s=period,
            )
            c = time.process_time()
            rep = run_method(ds, "ins", opts).report
            cpu = time.process_time() - c
            rate = rep["imu_steps"] / rep["wall_s"]
            if steps == 20:
                best = max(best, rate)
            print(
                f"  {model:6s} chunk {steps:2d}, states at {1 / period:3.0f} Hz: "
                f"{rep['imu_steps']} steps in {rep['wall_s']:.2f} s wall ({cpu:.2f} s CPU)"
                f" = {rate:6.0f} IMU steps/s, real-time factor {rep['realtime_factor']:.0f}"
            )
    verdict = "met" if best >= TARGET else "MISSED"
    print(
        f"default settings (chunk 20, 10 Hz states): best {best:.0f} IMU steps/s, "
        f"target {TARGET}: {verdict}"
    )
    return best


def village(n_seeds: int) -> None:
    """The simulator's village flight (paper noise levels, GPS 1 Hz with outages at 15, 40,
    65, 90 s), IMU + GPS + magnetometer + sonar, ground-truth start, both models."""
    from svains.sim.config import SimConfig
    from svains.sim.simulate import simulate

    for model in ("biased", "paper"):
        rows, nees_by_seed, growth = [], [], []
        for seed in range(n_seeds):
            cfg = SimConfig(seed=seed)
            cfg.camera.enabled = False
            with tempfile.TemporaryDirectory() as tmp:
                ds = load_dataset(simulate(cfg, Path(tmp) / "village"))
                res = run_method(
                    ds, "ins", RunOptions(model=model, init=InitOptions(mode="groundtruth"))
                )
            rep = res.report
            rows.append(
                (
                    rep["position_rmse_with_gps_m"],
                    rep["position_rmse_m"],
                    rep["position_within_3sigma"],
                    rep["nees_mean"],
                )
            )
            nees_by_seed.append(nees_series(res.t_ns, res.x, res.P9, ds.groundtruth)[1])
            growth.append([o["growth_m"] for o in rep["gps_outages"]])
        r = np.array(rows)
        n = min(len(s) for s in nees_by_seed)
        anees_t = np.mean([s[:n] for s in nees_by_seed], axis=0)  # average over seeds per step
        lo, hi = chi2.ppf([0.025, 0.975], 9 * n_seeds) / n_seeds
        g = np.array(growth)
        print(f"village, {model} model, {n_seeds} seeds:")
        print(
            f"  position RMSE with GPS: mean {r[:, 0].mean():.3f} m (max {r[:, 0].max():.3f});"
            f" whole flight incl. outages: mean {r[:, 1].mean():.3f} m"
        )
        print(
            "  error growth per outage (m), mean over seeds: "
            + ", ".join(f"{v:.2f}" for v in g.mean(axis=0))
            + "; max: "
            + ", ".join(f"{v:.2f}" for v in g.max(axis=0))
        )
        print(
            f"  3-sigma bounds contain the position error (per axis): mean {r[:, 2].mean():.4f},"
            f" min {r[:, 2].min():.4f}"
        )
        print(
            f"  average NEES (9 dof) over seeds and time: {anees_t.mean():.2f}; 95% interval for"
            f" a {n_seeds}-run average [{lo:.2f}, {hi:.2f}]; steps inside: "
            f"{np.mean((anees_t >= lo) & (anees_t <= hi)):.3f}"
        )


def euroc() -> None:
    """Free-inertial drift over 5 s windows restarted from ground truth; static-start bias."""
    from svains.models.state import BIASED as LAYOUT
    from svains.replay.drift import drift_windows

    ds = load_dataset(DATA)
    for model in ("biased", "paper"):
        w = drift_windows(ds, model, 5.0)
        pos = np.array([x.position_error_m for x in w])
        vel = np.array([x.velocity_error_mps for x in w])
        att = np.array([x.attitude_error_deg for x in w])
        print(
            f"EuRoC V1_01, {model} model, {len(w)} windows of 5 s from ground truth: position "
            f"error mean {pos.mean():.3f} m (median {np.median(pos):.3f}, max {pos.max():.3f}); "
            f"velocity mean {vel.mean():.3f} m/s; attitude mean {att.mean():.3f} deg"
            f" (max {att.max():.3f})"
        )
    init = initialise(ds, LAYOUT, InitOptions(mode="static"))
    gt = ds.groundtruth.bg_B[0]
    err = (init.x[13:16] - gt) * 1e3
    print(
        "static start (first 2 s), biased model: gyro bias "
        + ", ".join(f"{v:+.5f}" for v in init.x[13:16])
        + " rad/s vs ground truth "
        + ", ".join(f"{v:+.5f}" for v in gt)
        + " (error "
        + ", ".join(f"{v:+.2f}" for v in err)
        + " mrad/s); accelerometer bias starts at 0 (ground truth "
        + ", ".join(f"{v:+.4f}" for v in ds.groundtruth.ba_B[0])
        + " m/s²)"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--village", type=int, default=0, help="number of simulated seeds (0: skip)")
    ap.add_argument("--euroc", action="store_true", help="EuRoC drift windows and static bias")
    args = ap.parse_args()
    if not DATA.is_dir():
        print(f"missing {DATA}")
        return 1
    throughput()
    if args.euroc:
        euroc()
    if args.village:
        village(args.village)
    return 0


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        sys.exit(main())
