"""Real-MAV keyframes, as close as the shared data allow: rendered stereo images along real EuRoC
flights, an IMU as noisy as a flying MAV's, frames 0.05-7 s apart. Plain script (not a timed
test).

The one data set a user brings that ``bench/irregular_frames.py`` cannot stand in for is a
real MAV's keyframes: real images (so the image front end, its tracking and re-acquisition
across seconds, its RANSAC), a real IMU and a static start. The shared data have no images of a
flying MAV, so this bench builds the nearest thing:

- ``svains simulate --trajectory`` along the shared EuRoC ground truth (``V1_02_medium`` and
  ``V2_02_medium``: both start at rest on the floor), ``--duration`` s, stereo rendered at
  20 Hz, the simulator's EuRoC camera mount and intrinsics, no GPS, magnetometer or sonar;
- the IMU of the ``adis16448`` preset with its white noise multiplied by ``--vibration``
  (default gyro x5.5, accelerometer x7.9: what EuRoC's MAV measures at rest with its rotors
  on, the [low-rate page](../docs/results/low-rate.md)), while ``imu0/sensor.yaml`` keeps the
  data sheet's densities, as a user's Kalibr file would: the filter must find the platform's
  noise itself;
- per seed a random subset of the frames, every next gap drawn log-uniformly in
  ``[--min-gap, --max-gap]`` (``irregular_frames.draw_frames``, the same walk and random
  stream as there);
- each method through ``svains.evaluation.run`` with ``svains run``'s defaults and
  ``--images --no-gps --no-mag`` (static start, the default init); ``--features`` adds the same
  runs on the simulator's ``features0`` of the same frames (the front end's share of the error).

The rendered data sets are cached in ``--cache`` (default ``~/.cache/svains-bench``; about
2 minutes and 60 MB per 60 s flight), keyed by flight, seed, duration and vibration.

    python bench/rendered_keyframes.py [--flights V1_02 V2_02] [--seeds 0-2]
        [--methods 3d lc vo] [--features] [--duration 60] [--vibration 5.5 7.9]
        [--min-gap 0.05] [--max-gap 7] [--fail-ate 1] [--jobs 2] [--cache DIR] [--verbose]
        [--set KEY=VALUE ...]

ATE is the report's ``ate_rmse_m`` (se3-aligned, as ``svains run`` prints for a local start);
NEES the report's 9-dof mean and its blocks.
"""

from __future__ import annotations

import argparse
import math
import re
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from faults import parse_seeds
from irregular_frames import (
    FRAME_STREAM,
    draw_frames,
    fmt_blocks,
    keep_frames,
    one_line,
    report_figures,
)
from real_faults import warned_checks
from threadpoolctl import threadpool_limits

from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.run import run_method
from svains.replay import resolve_config
from svains.sim.config import ImuConfig, SimConfig
from svains.sim.simulate import simulate

S = 1_000_000_000
HERE = Path(__file__).resolve().parent
TRAJECTORIES = HERE.parent.parent / "shared" / "data" / "trajectories"
FLIGHTS = {"V1_02": "euroc_V1_02_medium_groundtruth.tum",
           "V2_02": "euroc_V2_02_medium_groundtruth.tum",
           "MH_03": "euroc_MH_03_medium_groundtruth.tum"}  # fmt: skip
CAMERA_HZ = 20.0


def cache_root(arg: str | None) -> Path:
    return Path(arg) if arg else Path.home() / ".cache" / "svains-bench"


def flight_dir(cache: Path, flight: str, seed: int, duration_s: float,
               vibration: tuple[float, float]) -> Path:  # fmt: skip
    tag = f"{flight}_s{seed}_d{duration_s:g}_vg{vibration[0]:g}_va{vibration[1]:g}"
    return cache / "rendered_keyframes" / tag


def nominal_calibration(root: Path, imu: ImuConfig, vibration: tuple[float, float]) -> None:
    """Write the data sheet's white-noise densities into ``imu0/sensor.yaml`` (the simulated
    noise is ``vibration`` times larger)."""
    path = root / "mav0" / "imu0" / "sensor.yaml"
    text = path.read_text()
    sq = math.sqrt(imu.rate_hz)
    for key, std, k in (("gyroscope_noise_density", imu.gyro_noise_std, vibration[0]),
                        ("accelerometer_noise_density", imu.accel_noise_std, vibration[1])):
        text, n = re.subn(rf"^{key}:.*$", f"{key}: {std / k / sq:.6e}", text, flags=re.M)
        if n != 1:
            raise RuntimeError(f"{path}: no single '{key}' line to rewrite")
    path.write_text(text)


def rendered_flight(job: tuple[str, int, float, tuple[float, float], str]) -> Path:
    """Simulate (or find in the cache) one flight; returns its data-set root."""
    flight, seed, duration_s, vibration, cache = job
    root = flight_dir(Path(cache), flight, seed, duration_s, vibration)
    if (root / "mav0" / "svains_complete.yaml").exists():
        return root
    cfg = SimConfig(scenario="trajectory", duration_s=duration_s, seed=seed)
    cfg.trajectory.tum_path = str(TRAJECTORIES / FLIGHTS[flight])
    imu = ImuConfig.preset("adis16448")
    imu.gyro_noise_std *= vibration[0]
    imu.accel_noise_std *= vibration[1]
    cfg.imu = imu
    cfg.camera.rate_hz = CAMERA_HZ
    cfg.gps.enabled = cfg.mag.enabled = cfg.sonar.enabled = False
    with threadpool_limits(limits=1):
        simulate(cfg, root, overwrite=True)
    nominal_calibration(root, imu, vibration)
    return root


def keyframes(root: Path, seed: int, lo_s: float, hi_s: float) -> tuple[Dataset, np.ndarray]:
    """The data set with its images and features thinned to the seed's keyframes."""
    ds = load_dataset(root)
    assert ds.left is not None and ds.right is not None
    times = np.intersect1d(ds.left.t_ns, ds.right.t_ns)
    kept = times[draw_frames(times, np.random.default_rng([FRAME_STREAM, seed]), lo_s, hi_s)]
    features = ds.features
    return replace(ds, left=ds.left.rows(np.isin(ds.left.t_ns, kept)),
                   right=ds.right.rows(np.isin(ds.right.t_ns, kept)),
                   features=None if features is None else keep_frames(features, kept)), kept


@dataclass
class Run:
    flight: str
    seed: int
    method: str
    source: str
    frames: int = 0
    max_gap_s: float = math.nan
    ate: float = math.nan
    nees: float = math.nan
    blocks: dict[str, float] = field(default_factory=dict)
    fused: str = "-"
    wall_s: float = math.nan
    error: str | None = None
    warned: tuple[str, ...] = ()  # the report's input checks that warned

    def failed(self, fail_ate: float) -> bool:
        return self.error is not None or not (self.ate <= fail_ate)


def run_one(job: tuple[str, str, int, str, str, float, float, tuple[str, ...]]) -> Run:
    root, flight, seed, method, source, lo_s, hi_s, sets = job
    row = Run(flight, seed, method, source)
    t0 = time.perf_counter()
    try:
        with threadpool_limits(limits=1):
            ds, kept = keyframes(Path(root), seed, lo_s, hi_s)
            row.frames, row.max_gap_s = int(kept.size), float(np.diff(kept).max() / S)
            switches = {"method": method, "use_gps": False, "use_mag": False,
                        "use_sonar": False, "vision.source": source}  # fmt: skip
            config = resolve_config(ds, build_config(None, list(sets), switches))
            result = run_method(ds, None, config)
            row.ate, row.nees, row.blocks, row.fused = report_figures(result, ds)
            row.warned = tuple(warned_checks(result.report))
    except Exception as exc:  # a stopped run is a result of this bench
        row.error = one_line(exc)
    row.wall_s = time.perf_counter() - t0
    return row


def table(rows: list[Run], fail_ate: float, verbose: bool) -> None:
    if verbose:
        print("| flight | seed | method | source | frames | max gap [s] | ATE [m] | NEES (9) | "
              "NEES blocks | fused | wall [s] | checks warned | status |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            status = r.error or ("ATE > limit" if r.failed(fail_ate) else "ok")
            print(f"| {r.flight} | {r.seed} | {r.method} | {r.source} | {r.frames} | "
                  f"{r.max_gap_s:.2f} | {r.ate:.3f} | {r.nees:.3g} | {fmt_blocks(r.blocks)} | "
                  f"{r.fused} | {r.wall_s:.1f} | {', '.join(r.warned) or '-'} | {status} |")
        print()
    print("| method | source | runs | mean ATE [m] | median | max | stopped | ATE > "
          f"{fail_ate:g} m | mean NEES (9) |")
    print("|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r.method, r.source) for r in rows}, key=lambda k: (k[1], k[0]))
    for method, source in keys:
        rs = [r for r in rows if r.method == method and r.source == source]
        ate = np.array([r.ate for r in rs if r.error is None])
        nees = np.array([r.nees for r in rs if r.error is None and math.isfinite(r.nees)])
        stopped = sum(r.error is not None for r in rs)
        over = sum(r.error is None and r.failed(fail_ate) for r in rs)

        def f(fn: Any, a: np.ndarray) -> str:
            return f"{fn(a):.3f}" if a.size else "-"

        print(f"| {method} | {source} | {len(rs)} | {f(np.mean, ate)} | {f(np.median, ate)} | "
              f"{f(np.max, ate)} | {stopped} | {over} | {f(np.mean, nees)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--flights", nargs="+", default=["V1_02", "V2_02"], choices=sorted(FLIGHTS))
    ap.add_argument("--seeds", default="0-2")
    ap.add_argument("--methods", nargs="+", default=["3d", "lc", "vo"],
                    choices=["3d", "tc", "lc", "vo"])
    ap.add_argument("--features", action="store_true",
                    help="also run on the simulator's features0 of the same frames")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--vibration", type=float, nargs=2, default=[5.5, 7.9],
                    metavar=("GYRO", "ACCEL"), help="white-noise factors over the data sheet")
    ap.add_argument("--min-gap", type=float, default=0.05)
    ap.add_argument("--max-gap", type=float, default=7.0)
    ap.add_argument("--fail-ate", type=float, default=1.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    seeds = parse_seeds(args.seeds)
    vib = (float(args.vibration[0]), float(args.vibration[1]))
    cache = str(cache_root(args.cache))
    t0 = time.perf_counter()
    sims = [(f, s, args.duration, vib, cache) for f in args.flights for s in seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        roots = list(pool.map(rendered_flight, sims))
        t_sim = time.perf_counter() - t0
        sources = ["images", "features"] if args.features else ["images"]
        jobs = [(str(root), f, s, m, src, args.min_gap, args.max_gap, tuple(args.sets))
                for root, (f, s, *_rest) in zip(roots, sims, strict=True)
                for src in sources for m in args.methods]  # fmt: skip
        rows = list(pool.map(run_one, jobs))
    print(f"## Rendered keyframes: flights {', '.join(args.flights)}, seeds {args.seeds}, "
          f"{args.duration:g} s, gaps {args.min_gap:g}-{args.max_gap:g} s, IMU white noise x"
          f"{vib[0]:g} (gyro) / x{vib[1]:g} (accel) over its sensor.yaml\n")
    table(rows, args.fail_ate, args.verbose)
    print(f"\nsimulation {t_sim:.0f} s (cache {cache}), total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
