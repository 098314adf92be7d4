"""Benchmark of the navigation methods as users run them (issues 6 and 11).

1. Cost of one vision observation model evaluation (all sigma points x all features): 3d, tc, lc.
2. Real-time factor of every method (``3d`` first, then ins, vo, lc, tc; the vision methods
   from images) on a simulated 20 Hz 752x480 village flight of ``--duration`` s: each run is a
   fresh process (imports, numba cache and front-end set-up included, as for a user), first
   alone, best of ``--repeat``, then as two identical processes started together (the second
   one launched by this script), with the per-stage profile of the image source and the load
   average before each run. Threads per numerical library follow ``SVAINS_THREADS`` (default 1,
   ``svains.threads``); ``--threads N`` sets it for the runs.
3. With ``--extras``: ``3d`` with the other setting of the IMU motion prior (accuracy) and its
   filter side alone on the recorded tracks (CPU time). ``--profile`` adds a cProfile listing
   (main thread CPU) of one ``3d`` run.

Plain script: prints its figures; timings depend on the machine's load, printed beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

METHODS = ("3d", "ins", "vo", "lc", "tc")
RUN_FLAGS: list[str] = []  # given to every run (``--rotation``), set by ``main``


def _best_of(fn, repeat: int = 7, number: int = 20) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def bench_models() -> None:
    from _vision_truth import make_rig, sigma_cloud, two_frames
    from svains.models.vision_3d import predict_pixels_3d
    from svains.models.vision_lc import predict_egomotion_lc
    from svains.models.vision_tc import predict_pixels_tc

    rig = make_rig()
    print("vision model evaluation, S sigma points x M features (best of 7, ms per call)")
    print(f"{'S':>4} {'M':>5} {'3d':>8} {'tc':>8} {'lc':>8}")
    for s, m in ((25, 100), (37, 100), (37, 200), (37, 400)):
        tf = two_frames(rig, 0.5, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=m)
        X = sigma_cloud(tf.x_k, n=s)
        t3 = _best_of(lambda: predict_pixels_3d(X, tf.p_Ckm1_F, 0.5, rig))  # noqa: B023
        ttc = _best_of(
            lambda: predict_pixels_tc(X, tf.uv_left_prev, tf.uv_right_prev, 0.5, rig)  # noqa: B023
        )
        tlc = _best_of(lambda: predict_egomotion_lc(X, 0.5, rig))  # noqa: B023
        print(f"{s:>4} {m:>5} {t3 * 1e3:8.3f} {ttc * 1e3:8.3f} {tlc * 1e3:8.3f}")


def simulate_20hz(out: Path, duration_s: float) -> Path:
    """The bench data set: the village flight, stereo rendered at 20 Hz, 752x480."""
    from dataclasses import replace

    from svains.sim import SimConfig, simulate

    cfg = SimConfig()
    cfg = replace(cfg, duration_s=duration_s, camera=replace(cfg.camera, rate_hz=20.0))
    return simulate(cfg, out)


def _launch(data: Path, method: str, flags: list[str], env: dict[str, str]) -> subprocess.Popen:
    cmd = [sys.executable, str(Path(__file__).with_name("_method_run.py")), str(data), method]
    return subprocess.Popen([*cmd, *RUN_FLAGS, *flags], stdout=subprocess.PIPE, env=env, text=True)


def _result(proc: subprocess.Popen) -> dict:
    out, _ = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark run failed with exit code {proc.returncode}")
    return json.loads(out.strip().splitlines()[-1])


def timed_runs(data: Path, method: str, n_parallel: int, repeat: int, env: dict[str, str],
               flags: list[str] | None = None) -> list[list[dict]]:
    """``repeat`` rounds of ``n_parallel`` identical runs started together."""
    rounds = []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as barrier:
            f = [*(flags or []), "--barrier", barrier, "--peers", str(n_parallel)]
            procs = [_launch(data, method, f, env) for _ in range(n_parallel)]
            rounds.append([_result(p) for p in procs])
    return rounds


def _print_stages(run: dict) -> None:
    stages = run.get("stages_ms")
    if not stages:
        return
    print("    per stereo frame, ms (20 Hz: 5x real time = 10 ms, 2.5x = 20 ms):")
    for key, val in stages.items():
        print(f"      {key:<14} {val:7.2f}")


def bench_method(data: Path, method: str, repeat: int, env: dict[str, str], parallel: bool,
                 extras: bool) -> dict[str, float]:
    """Alone (best of ``repeat``) and two at once (the slower of the pair, best round)."""
    alone = [r[0] for r in timed_runs(data, method, 1, repeat, env)]
    best = max(alone, key=lambda r: r["rtf"])
    others = ", ".join(f"{r['rtf']:.2f}x at {r['load_avg']:.2f}" for r in alone if r is not best)
    print(f"{method}: alone, best of {len(alone)}: real-time factor {best['rtf']:.2f}x "
          f"({best['wall_s']:.2f} s wall, {best['cpu_s']:.2f} s CPU for {best['data_s']:.1f} s; "
          f"load average {best['load_avg']:.2f} on {os.cpu_count()} cores"
          + (f"; other runs {others}" if others else "")
          + f"); position RMSE {best['rmse_m']:.4f} m"
          + (f"; front end {best['frontend_status']}" if best.get("frontend_status") else ""))
    _print_stages(best)
    out = {"alone": best["rtf"]}
    if parallel:
        rounds = timed_runs(data, method, 2, repeat, env)
        slow = [min(r, key=lambda x: x["rtf"]) for r in rounds]
        worst_best = max(slow, key=lambda r: r["rtf"])
        pair = next(r for r in rounds if worst_best in r)
        others = ", ".join(f"{r['rtf']:.2f}x" for r in slow if r is not worst_best)
        print(f"{method}: two identical runs at once, best of {len(rounds)} rounds: "
              + " and ".join(f"{r['rtf']:.2f}x ({r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} s CPU)"
                             for r in pair)
              + f"; load average {worst_best['load_avg']:.2f}"
              + (f"; other rounds' slower run {others}" if others else ""))
        _print_stages(worst_best)
        out["parallel"] = worst_best["rtf"]
    if extras and method == "3d":
        ex = timed_runs(data, method, 1, 1, env, ["--extras"])[0][0]
        op = ex["other_prior"]
        print(f"3d {'with' if op['motion_prior'] else 'without'} the IMU motion prior: position "
              f"RMSE {op['rmse_m']:.4f} m (default: {ex['rmse_m']:.4f} m)")
        print(f"3d filter side only (recorded tracks replayed, {ex['frames']} frames): "
              f"{ex['replay_cpu_ms']:.2f} ms main-thread CPU, {ex['replay_wall_ms']:.2f} ms "
              "wall per frame")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=2, help="runs (rounds) per setting")
    ap.add_argument("--data", type=Path, default=None, help="reuse a simulated data set")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated flight, s")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--rotation", default=None, help="vision motion model (default: clone)")
    ap.add_argument("--threads", type=int, default=None, help="SVAINS_THREADS for the runs")
    ap.add_argument("--aided", action="store_true",
                    help="also fuse GPS, magnetometer and sonar (default: none, as issue 11's "
                    "`svains run ... --no-gps --no-mag --no-sonar`)")
    ap.add_argument("--no-parallel", action="store_true", help="skip the two-at-once runs")
    ap.add_argument("--extras", action="store_true", help="motion prior and filter replay")
    ap.add_argument("--profile", action="store_true", help="cProfile one 3d run")
    ap.add_argument("--no-models", action="store_true", help="skip the model evaluation costs")
    args = ap.parse_args()
    env = dict(os.environ)
    if args.rotation is not None:
        RUN_FLAGS[:] = ["--rotation", args.rotation]
    if args.aided:
        RUN_FLAGS.append("--aided")
    if args.threads is not None:
        env["SVAINS_THREADS"] = str(args.threads)
    print(f"threads per numerical library: SVAINS_THREADS={env.get('SVAINS_THREADS', '(1)')}; "
          f"vision.rotation={args.rotation or 'default (clone)'}; "
          + ("GPS, magnetometer and sonar fused" if args.aided else "no GPS, mag or sonar"))
    if not args.no_models:
        bench_models()
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data
        if data is None:
            t0 = time.perf_counter()
            data = simulate_20hz(Path(tmp) / "sim", args.duration)
            print(f"simulated {args.duration:.0f} s at 20 Hz with images in "
                  f"{time.perf_counter() - t0:.1f} s")
        if args.profile:
            run = timed_runs(data, "3d", 1, 1, env, ["--profile"])[0][0]
            print(run["profile"])
        summary = {}
        for m in args.methods.split(","):
            summary[m] = bench_method(data, m, args.repeat, env, not args.no_parallel,
                                      args.extras)
        print("summary, real-time factor (alone / two at once):")
        for m, s in summary.items():
            print(f"  {m:<4} {s['alone']:7.2f}x" + (f" / {s['parallel']:.2f}x" if "parallel" in s
                                                      else ""))
        print(f"load average at the end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):
        main()
