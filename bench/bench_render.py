"""Simulator speed: stereo pairs rendered per second at 752x480, and a full 110 s village flight
with images at 2 Hz (the issue's targets: >= 20 pairs/s, flight in under a minute).

Plain script: ``python bench/bench_render.py [--skip-flight]``. Timings depend on the machine's
load; the figures printed are wall-clock seconds.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from svains.sim import SimConfig, simulate
from svains.sim.render import NoiseBank, Renderer, finish_image
from svains.sim.simulate import build_scene


def bench_pairs(n_pairs: int = 60) -> None:
    t0 = time.perf_counter()
    scene = build_scene(SimConfig(duration_s=110.0, seed=0))
    t_build = time.perf_counter() - t0
    renderer = Renderer(scene.world, scene.rig)
    t = np.linspace(0.0, 109.0, n_pairs)
    truth = scene.trajectory.evaluate(t)
    rng = np.random.default_rng(0)
    bank = NoiseBank((scene.rig.height, scene.rig.width), rng)
    renderer.render_pair(truth.R_W_B[0], truth.p_W_B[0], 0.0)  # warm-up: texture pyramids
    t0 = time.perf_counter()
    c0 = time.process_time()
    for k in range(n_pairs):
        left, right = renderer.render_pair(truth.R_W_B[k], truth.p_W_B[k], float(t[k]))
        finish_image(left, 1.0, 2.0, rng, bank)
        finish_image(right, 1.0, 2.0, rng, bank)
    dt = time.perf_counter() - t0
    cpu = time.process_time() - c0
    print(f"world build: {t_build:.2f} s ({len(scene.world.faces)} faces, "
          f"{len(scene.world.landmarks_W)} landmarks)")
    print(f"render 752x480 stereo: {n_pairs / dt:.1f} pairs/s ({1e3 * dt / n_pairs:.1f} ms/pair,"
          f" {n_pairs} pairs along the village flight, incl. noise/exposure)")
    print(f"render CPU time (both threads): {1e3 * cpu / n_pairs:.1f} ms/pair")


def bench_flight() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        root = simulate(SimConfig(duration_s=110.0, seed=0), Path(tmp) / "village")
        dt = time.perf_counter() - t0
        n = len(os.listdir(root / "mav0" / "cam0" / "data"))
    print(f"110 s village flight, images at 2 Hz ({n} stereo pairs written as PNG): {dt:.1f} s")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = SimConfig(duration_s=110.0, seed=0)
        cfg.camera.render_images = False
        simulate(cfg, Path(tmp) / "features")
    print(f"110 s village flight, features only (--no-images): {time.perf_counter() - t0:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--skip-flight", action="store_true", help="only time the renderer")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    bench_pairs()
    if not args.skip_flight:
        bench_flight()


if __name__ == "__main__":
    main()
