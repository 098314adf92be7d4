"""Data-set reading and trajectory evaluation timings on the real EuRoC micro set.

Prints wall-clock figures (best of 3): loading the ASL folder (CSV + yaml, images listed not
decoded), decoding one image, walking every event in time order, and the se3/posyaw ATE of the
2895-pose ground truth against a perturbed copy through evo.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from svains.datasets import iter_events, load_dataset
from svains.evaluation.metrics import ate, rpe
from svains.geometry.rotation import quat_multiply, rotmat_to_quat, so3_exp

DATA = Path(__file__).resolve().parents[1].parent / "shared/data/euroc_v101_micro"


def best_of(fn: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    # The micro set's 4 absent images would log a warning on every load.
    logging.getLogger("svains").setLevel(logging.ERROR)
    print(f"load_dataset(euroc_v101_micro): {best_of(lambda: load_dataset(DATA)) * 1e3:.1f} ms")
    ds = load_dataset(DATA)
    print(f"decode one 752x480 image: {best_of(lambda: ds.left.load(0)) * 1e3:.2f} ms")
    n = sum(1 for _ in iter_events(ds))
    dt = best_of(lambda: sum(1 for _ in iter_events(ds)))
    print(f"iter_events over {n} samples: {dt * 1e3:.1f} ms ({dt / n * 1e9:.0f} ns/event)")
    gt = ds.groundtruth
    R = so3_exp([0.2, -0.1, 1.0])
    rng = np.random.default_rng(0)
    p = gt.p_W_B @ R.T + 1.0 + rng.normal(scale=0.02, size=gt.p_W_B.shape)
    q = quat_multiply(rotmat_to_quat(R), gt.q_W_B_wxyz)
    args = (gt.t_ns, p, q, gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz)
    for align in ("se3", "posyaw"):
        dt = best_of(lambda a=align: ate(*args, align=a))
        print(f"ATE {align} ({gt.t_ns.size} poses, evo): {dt * 1e3:.0f} ms")
    dt = best_of(lambda: rpe(*args, delta_m=[1.0, 5.0]))
    print(f"RPE 1 m + 5 m ({gt.t_ns.size} poses, evo): {dt * 1e3:.0f} ms")


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        main()
