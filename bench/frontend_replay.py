"""Front-end CPU time per stage on a recorded run, for A/B comparisons of front-end code.

``record``: one ``3d`` run from images (as ``bench/_method_run.py``, no GPS, magnetometer or
sonar) saving the motion prior the filter handed the front end at every stereo pair (``None``
with the default ``VisionOptions.motion_prior=False``: the front end then predicts from its
last motion). ``replay``: the front end alone on the same pairs and priors, each pair copied
just before it is processed (fresh in cache, as a decoded image is), with CPU time
(``time.process_time``, all threads) in place of the wall clock in the per-stage timers, so
that two code versions run interleaved on a loaded machine compare fairly; best of
``--repeat`` runs per stage (the first run also pays one-time costs such as loading compiled
kernels). Also the median and mean egomotion error of the measured frames against the ground
truth (translation % of the step, rotation deg).

``python bench/frontend_replay.py record DATA PRIORS.pkl``
``python bench/frontend_replay.py replay DATA PRIORS.pkl [--repeat N]`` (prints one JSON line;
``PYTHONPATH=/other/src`` times another checkout on the same recording).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from svains.threads import limit_threads

STAGES = ("track", "detect", "stereo", "ransac", "pyramid", "rectify", "total")


def record(data: Path, out: Path) -> None:
    import svains.navigation.vision_sources as vs
    from svains.datasets.loader import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.options import InitOptions, RunOptions, VisionOptions
    from svains.replay import resolve_config

    priors: dict[int, object] = {}
    tracks_at = vs.ImageFrames.tracks_at

    def _tracks_at(self: vs.ImageFrames, t_ns: int, motion_prior: object = None) -> object:
        priors[int(t_ns)] = motion_prior
        return tracks_at(self, t_ns, motion_prior)  # type: ignore[arg-type]

    vs.ImageFrames.tracks_at = _tracks_at  # type: ignore[assignment,method-assign]
    ds = load_dataset(data)
    opts = RunOptions(method="3d", model="biased", init=InitOptions(mode="groundtruth"),
                      vision=VisionOptions(source="images"), use_gps=False, use_mag=False,
                      use_sonar=False)  # fmt: skip
    run_method(ds, "3d", resolve_config(ds, opts))
    out.write_bytes(pickle.dumps(priors))
    print(f"{len(priors)} priors recorded to {out}")


def replay(data: Path, priors_path: Path, repeat: int) -> dict[str, object]:
    from svains.datasets import load_dataset, stereo_pairs
    from svains.frontend.pipeline import StereoFrontend
    from svains.frontend.run import groundtruth_camera_poses

    ds = load_dataset(data)
    priors = pickle.loads(priors_path.read_bytes())
    t_ns, il, ir = stereo_pairs(ds)
    pairs = [(int(t), ds.left.load(int(a)), ds.right.load(int(b)))  # type: ignore[union-attr]
             for t, a, b in zip(t_ns, il, ir, strict=True) if int(t) in priors]  # fmt: skip
    rig = StereoFrontend.from_calibration(ds.cam0, ds.cam1).rig  # type: ignore[arg-type]
    T_W_C = groundtruth_camera_poses(ds.groundtruth, np.array([p[0] for p in pairs]),
                                     rig.R_B_C, rig.p_B_C)  # fmt: skip
    pose = {p[0]: T for p, T in zip(pairs, T_W_C, strict=True)}
    wall = time.perf_counter
    best: dict[str, float] = {}
    errs_t: list[float] = []
    errs_r: list[float] = []
    try:
        time.perf_counter = time.process_time  # the front end's stage clocks: CPU time
        for _ in range(max(repeat, 1)):
            fe = StereoFrontend.from_calibration(ds.cam0, ds.cam1)  # type: ignore[arg-type]
            per = {s: 0.0 for s in STAGES}
            errs_t, errs_r = [], []
            for t, left, right in pairs:
                tr = fe.process(t, left.copy(), right.copy(), priors[t])
                for s in STAGES:
                    per[s] += fe.stats.timings_ms.get(s, 0.0)
                if tr is not None and tr.egomotion is not None:
                    T_rel = np.linalg.inv(pose[tr.t_ns]) @ pose[tr.t_prev_ns]
                    R, p = T_rel[:3, :3], T_rel[:3, 3]
                    e = tr.egomotion
                    errs_t.append(100 * np.linalg.norm(e.p_Ck_Ckm1 - p) / max(np.linalg.norm(p),
                                                                                  1e-9))
                    dR = e.R_Ck_Ckm1 @ R.T
                    errs_r.append(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
            for s in STAGES:
                v = per[s] / len(pairs)
                best[s] = min(best.get(s, np.inf), v)
    finally:
        time.perf_counter = wall
    return {"frames": len(pairs), "cpu_ms": best, "measured": len(errs_t),
            "med_t_pct": float(np.median(errs_t)), "mean_t_pct": float(np.mean(errs_t)),
            "med_r_deg": float(np.median(errs_r)), "mean_r_deg": float(np.mean(errs_r))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("record", "replay"))
    ap.add_argument("data", type=Path)
    ap.add_argument("priors", type=Path)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    with limit_threads(None):
        if args.mode == "record":
            record(args.data, args.priors)
        else:
            sys.stdout.write(json.dumps(replay(args.data, args.priors, args.repeat)) + "\n")


if __name__ == "__main__":
    main()
