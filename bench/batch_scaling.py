"""Campaign throughput on a local Dask cluster: runs per minute with 1 and with 2 workers.

The campaign: ``3d`` on ``--runs`` seeds of a ``--duration`` s GPS-denied village flight
(feature-level simulation inside each task, stereo 5 Hz), one Dask task per run. Each cluster is
started and warmed up (imports, numba cache) before the clock starts, so the figure is the
steady throughput a long campaign sees. The load average and the cores the workers actually got
are printed beside every figure: on a shared machine (Linux groups a session's processes for
CPU sharing, ``sched_autogroup``) two workers may get no more CPU than one.

    python bench/batch_scaling.py [--runs 12] [--duration 20] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import tempfile
import time
from pathlib import Path

from svains.batch import parse_spec
from svains.batch.driver import dask_client, execute
from svains.batch.task import run_group


def _spec(runs: int, duration_s: float, first_seed: int) -> dict[str, object]:
    return {
        "name": "scaling",
        "scenarios": {"village": {"duration_s": duration_s, "camera.rate_hz": 5.0,
                                  "camera.render_images": False}},
        "methods": ["3d"], "seeds": list(range(first_seed, first_seed + runs)),
        "settings": {"init.mode": "groundtruth", "fusion.use_gps": False, "fusion.use_mag": False,
                     "vision.source": "features", "vision.rotation": "imu"},
    }  # fmt: skip


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def _cpu_s() -> float:
    """CPU seconds (user + system) this process has used."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def runs_per_minute(n_workers: int, runs: int, duration_s: float) -> tuple[float, int, float]:
    """Runs per minute of ``runs`` fresh runs on an ``n_workers`` local cluster, after one
    warm-up run per worker; how many failed; and the cores the workers used meanwhile (CPU
    seconds over wall seconds: below ``n_workers`` when the machine is shared)."""
    warm = parse_spec(_spec(n_workers, 2.0, 10_000)).tasks()
    tasks = parse_spec(_spec(runs, duration_s, 0)).tasks()
    failed = 0

    def count(result: object) -> None:
        nonlocal failed
        failed += getattr(result, "status", "ok") != "ok"

    with dask_client(n_workers=n_workers) as client, tempfile.TemporaryDirectory() as tmp:
        addresses = list(client.scheduler_info()["workers"])
        futures = [client.submit(run_group, [t], workers=[a], pure=False)
                   for t, a in zip(warm, addresses, strict=True)]  # fmt: skip
        client.gather(futures)
        cpu0 = sum(client.run(_cpu_s).values())
        t0 = time.perf_counter()
        execute(tasks, Path(tmp), client, count)
        wall = time.perf_counter() - t0
        cores = (sum(client.run(_cpu_s).values()) - cpu0) / wall
    return 60.0 * runs / wall, failed, cores


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--duration", type=float, default=20.0, help="flight length [s]")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger("distributed").setLevel(logging.ERROR)
    print(f"{os.cpu_count()} cores; {args.runs} runs of 3d on a {args.duration:g} s village")
    rate: dict[int, float] = {}
    for n in args.workers:
        before = loadavg()
        rate[n], failed, cores = runs_per_minute(n, args.runs, args.duration)
        print(f"{n} worker(s): {rate[n]:.1f} runs/min, the workers used {cores:.2f} cores "
              f"({failed} failed; load average before {before}, after {loadavg()})", flush=True)
    if 1 in rate:
        for n in (k for k in rate if k != 1):
            print(f"speed-up with {n} workers: {rate[n] / rate[1]:.2f}x")


if __name__ == "__main__":
    main()
