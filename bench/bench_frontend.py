"""Stereo front-end timing per stereo pair, per stage, in ms (real images).

Runs the sparse path (FAST + KLT + row search) over the first frames of
``../shared/data/euroc_v101_micro`` (752x480, raw images with distortion: a static MAV, so new
corners are only sought every few frames) and of ``../shared/data/kitti_stereo_a`` (1226x370,
already rectified: a car at 1.2 m per frame, so corners are sought on every frame) and of a
simulated 752x480 village flight (2 Hz, 1 m per frame: the moving-camera cost at 752x480), the
dense
paths (SGBM; ELAS when the optional ``pyelas`` binding is installed) on EuRoC, then RANSAC
egomotion alone. Per stage it prints the median over frames (frame 0 excluded) and the mean
(stages skipped on a frame count as 0 there, so means add up to the amortised cost), each the
best of ``--repeat`` runs (default 3): load from other processes only ever inflates a timing,
so the best run is the closest to the machine's own speed.

Usage: ``python bench/bench_frontend.py [--repeat N] [--sparse-only]``.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset, stereo_pairs
from svains.datasets.types import Dataset
from svains.frontend.egomotion import RansacOptions, estimate_egomotion
from svains.frontend.pipeline import FrontendOptions, StereoFrontend
from svains.frontend.stereo import StereoMatchOptions, elas_available

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
FRAMES = 40
STAGES = ("rectify", "pyramid", "dense", "track", "stereo", "ransac", "detect",
          "total")  # fmt: skip
Images = list[tuple[int, np.ndarray, np.ndarray]]


def _load(name: str) -> tuple[Dataset, Images]:
    return _load_path(DATA / name)


def _load_path(root: Path) -> tuple[Dataset, Images]:
    ds = load_dataset(root)
    t_ns, il, ir = stereo_pairs(ds)
    n = min(FRAMES, t_ns.size)
    assert ds.left is not None and ds.right is not None
    return ds, [(int(t_ns[i]), ds.left.load(int(il[i])), ds.right.load(int(ir[i])))
                for i in range(n)]  # fmt: skip


def _run(method: str, images: Images, ds: Dataset) -> dict[str, float]:
    """Per stage: ``<stage>`` median and ``<stage>_mean`` over frames 1.. of one run."""
    assert ds.cam0 is not None and ds.cam1 is not None
    fe = StereoFrontend.from_calibration(
        ds.cam0, ds.cam1, FrontendOptions(stereo=StereoMatchOptions(method=method))
    )
    per: dict[str, list[float]] = {s: [] for s in STAGES}
    inl: list[int] = []
    searched = 0
    for k, (t, left, right) in enumerate(images):
        fe.process(t, left, right)
        if k == 0:
            continue
        inl.append(fe.stats.inliers)
        searched += "detect" in fe.stats.timings_ms
        for s in STAGES:
            per[s].append(fe.stats.timings_ms.get(s, 0.0))
    out = {s: float(np.median(v)) for s, v in per.items()}
    out.update({f"{s}_mean": float(np.mean(v)) for s, v in per.items()})
    out["inliers"] = float(np.median(inl))
    out["searched_pct"] = 100.0 * searched / max(len(images) - 1, 1)
    return out


def _best_of(method: str, images: Images, ds: Dataset, repeat: int) -> dict[str, float]:
    runs = [_run(method, images, ds) for _ in range(max(repeat, 1))]
    return {k: min(r[k] for r in runs) for k in runs[0]}


def _table(title: str, rows: dict[str, dict[str, float]]) -> None:
    print(title)
    print(f"{'stage':<12}" + "".join(f"{m + ' med':>14}{m + ' mean':>14}" for m in rows))
    for s in STAGES:
        print(f"{s:<12}" + "".join(f"{r[s]:>14.2f}{r[s + '_mean']:>14.2f}" for r in rows.values()))
    print(f"{'inliers':<12}" + "".join(f"{r['inliers']:>14.0f}{'':>14}" for r in rows.values()))
    print("frames with a corner search: "
          + ", ".join(f"{m} {r['searched_pct']:.0f} %" for m, r in rows.items()))  # fmt: skip


def main() -> int:
    repeat = int(sys.argv[sys.argv.index("--repeat") + 1]) if "--repeat" in sys.argv else 3
    sparse_only = "--sparse-only" in sys.argv
    if not (DATA / "euroc_v101_micro").is_dir():
        print(f"missing data: {DATA / 'euroc_v101_micro'}")
        return 1
    print(f"ms per stereo pair, best of {repeat} runs (dense: 1 run); "
          f"load average at start {os.getloadavg()[0]:.1f}")  # fmt: skip
    ds, images = _load("euroc_v101_micro")
    methods = ["sparse"] if sparse_only else ["sparse", "sgbm"]
    if not sparse_only and elas_available():
        methods.append("elas")
    rows = {m: _best_of(m, images, ds, repeat if m == "sparse" else 1) for m in methods}
    _table(f"EuRoC micro, {len(images)} pairs 752x480 (raw, rectified per point)", rows)
    if not sparse_only and not elas_available():
        print("(ELAS not timed: the optional pyelas binding is not installed)")
    if (DATA / "kitti_stereo_a").is_dir():
        kds, kimages = _load("kitti_stereo_a")
        _table(f"KITTI, {len(kimages)} pairs 1226x370 (moving car)",
               {"sparse": _best_of("sparse", kimages, kds, repeat)})  # fmt: skip

    with tempfile.TemporaryDirectory() as tmp:
        from svains.sim.config import SimConfig
        from svains.sim.simulate import simulate

        cfg = SimConfig()
        cfg.duration_s = 12.0
        simulate(cfg, Path(tmp) / "sim")
        sds, simages = _load_path(Path(tmp) / "sim")
        _table(f"Simulated village flight, {len(simages)} pairs 752x480 (moving, 1 m per frame)",
               {"sparse": _best_of("sparse", simages, sds, repeat)})  # fmt: skip

    # RANSAC egomotion alone on 250 synthetic features (30 % outliers), 50 hypotheses.
    assert ds.cam0 is not None and ds.cam1 is not None
    rig = StereoFrontend.from_calibration(ds.cam0, ds.cam1).rig
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-2, 2, 250), rng.uniform(-1, 1, 250), rng.uniform(1, 8, 250)]
    q = p + np.array([0.01, 0.0, 0.02])
    uvl = rig.project(q) + rng.normal(0, 0.2, (250, 2))
    uvr = rig.project_right(q) + rng.normal(0, 0.2, (250, 2))
    out = rng.random(250) < 0.3
    uvl[out] += 10.0
    times = []
    for _ in range(50):
        t0 = time.perf_counter()
        estimate_egomotion(p, uvl, uvr, rig, RansacOptions(), p_cur=rig.triangulate(uvl, uvr))
        times.append(time.perf_counter() - t0)
    print(f"ransac egomotion alone (250 features, 50 hypotheses): best "
          f"{min(times) * 1e3:.2f} ms, median {np.median(times) * 1e3:.2f} ms of 50")  # fmt: skip
    return 0


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        sys.exit(main())
