"""Benchmark of the vision methods (issue 6).

1. Cost of one vision observation model evaluation (all sigma points x all features): 3d, tc, lc.
2. Real-time factor and per-stage profile of ``3d`` from images on a simulated 20 Hz 752x480
   village flight (needs the simulator ``svains.sim.simulate``; skipped with a note otherwise).

Plain script: prints its figures; timings depend on the machine's load.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _vision_truth import make_rig, sigma_cloud, two_frames
from svains.models.vision_3d import predict_pixels_3d
from svains.models.vision_lc import predict_egomotion_lc
from svains.models.vision_tc import predict_pixels_tc


def _best_of(fn, repeat: int = 7, number: int = 20) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def bench_models() -> None:
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


def bench_images_3d(duration_s: float = 20.0) -> None:
    """``3d`` from rendered images (front end + filter) on a 20 Hz 752x480 village flight."""
    from dataclasses import replace

    from svains.datasets.loader import load_dataset
    from svains.navigation.options import InitOptions, RunOptions
    from svains.navigation.runner import run_method
    from svains.navigation.vision import tune_run_options
    from svains.sim import SimConfig, simulate

    with tempfile.TemporaryDirectory() as tmp:
        cfg = SimConfig()
        cfg = replace(cfg, duration_s=duration_s, camera=replace(cfg.camera, rate_hz=20.0))
        t0 = time.perf_counter()
        root = simulate(cfg, Path(tmp) / "sim")
        took = time.perf_counter() - t0
        print(f"simulated {duration_s:.0f} s at 20 Hz with images in {took:.1f} s")
        ds = load_dataset(root)
        for rotation in ("imu",):
            opts = RunOptions(model="biased", init=InitOptions(mode="groundtruth"),
                              method_options={"source": "images", "rotation": rotation})
            opts = tune_run_options(ds, "3d", opts)
            prof = cProfile.Profile()
            prof.enable()
            res = run_method(ds, "3d", opts)
            prof.disable()
            rep = res.report
            print(f"3d ({rotation}) from images: {rep['data_duration_s']:.1f} s of data in "
                  f"{rep['wall_s']:.2f} s -> real-time factor {rep['realtime_factor']:.2f}x "
                  f"(target >= 3x); position RMSE {rep['position_rmse_m']:.3f} m")
            stats = pstats.Stats(prof)
            print("per-stage profile (cumulative s, top entries):")
            stats.sort_stats("cumulative").print_stats(
                r"(frontend/pipeline|frontend/egomotion|frontend/tracking|frontend/stereo|"
                r"frontend/features|navigation/vision|navigation/ins|filter/ukf|models/imu)"
            )


if __name__ == "__main__":
    bench_models()
    bench_images_3d()
