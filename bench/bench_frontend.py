"""Stereo front-end timing per 752x480 pair (real EuRoC micro images), per stage, in ms.

Runs the sparse path (FAST + KLT + row search) and the dense paths (SGBM; ELAS when the optional
``pyelas`` binding is installed) over the first frames of ``../shared/data/euroc_v101_micro``,
then times RANSAC egomotion alone. Prints medians over frames (the first frame excluded).
Machine load from other processes inflates the numbers; rerun on an idle machine to quote.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset, stereo_pairs
from svains.frontend.egomotion import RansacOptions, estimate_egomotion
from svains.frontend.pipeline import FrontendOptions, StereoFrontend
from svains.frontend.stereo import StereoMatchOptions, elas_available

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"
FRAMES = 40
STAGES = ("rectify", "pyramid", "dense", "track", "stereo", "ransac", "detect", "stereo_new",
          "total")  # fmt: skip


def _run(method: str, images: list[tuple[int, np.ndarray, np.ndarray]], ds) -> dict[str, float]:  # type: ignore[no-untyped-def]
    fe = StereoFrontend.from_calibration(
        ds.cam0, ds.cam1, FrontendOptions(stereo=StereoMatchOptions(method=method))
    )
    per: dict[str, list[float]] = {s: [] for s in STAGES}
    inl: list[int] = []
    for k, (t, left, right) in enumerate(images):
        fe.process(t, left, right)
        if k == 0:
            continue
        inl.append(fe.stats.inliers)
        for s in STAGES:
            per[s].append(fe.stats.timings_ms.get(s, 0.0))
    out = {s: float(np.median(v)) for s, v in per.items()}
    out["inliers"] = float(np.median(inl))
    return out


def main() -> int:
    if not DATA.is_dir():
        print(f"missing data: {DATA}")
        return 1
    ds = load_dataset(DATA)
    t_ns, il, ir = stereo_pairs(ds)
    n = min(FRAMES, t_ns.size)
    images = [(int(t_ns[i]), ds.left.load(int(il[i])), ds.right.load(int(ir[i]))) for i in range(n)]
    print(f"EuRoC micro, {n} stereo pairs 752x480; median ms per pair (frame 0 excluded)")
    methods = ["sparse", "sgbm"] + (["elas"] if elas_available() else [])
    if not elas_available():
        print("(ELAS not timed: the optional pyelas binding is not installed)")
    rows = {m: _run(m, images, ds) for m in methods}
    print(f"{'stage':<12}" + "".join(f"{m:>10}" for m in methods))
    for s in (*STAGES, "inliers"):
        print(f"{s:<12}" + "".join(f"{rows[m][s]:>10.2f}" for m in methods))

    # RANSAC egomotion alone on 250 synthetic features (30 % outliers), 50 hypotheses.
    fe = StereoFrontend.from_calibration(ds.cam0, ds.cam1)
    rig = fe.rig
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-2, 2, 250), rng.uniform(-1, 1, 250), rng.uniform(1, 8, 250)]
    q = p + np.array([0.01, 0.0, 0.02])
    uvl = rig.project(q) + rng.normal(0, 0.2, (250, 2))
    uvr = rig.project_right(q) + rng.normal(0, 0.2, (250, 2))
    out = rng.random(250) < 0.3
    uvl[out] += 10.0
    reps = 50
    t0 = time.perf_counter()
    for _ in range(reps):
        estimate_egomotion(p, uvl, uvr, rig, RansacOptions(), p_cur=rig.triangulate(uvl, uvr))
    print(f"ransac egomotion alone (250 features, 50 hypotheses): "
          f"{(time.perf_counter() - t0) / reps * 1e3:.2f} ms")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
