"""One timed navigation run in its own process, for ``bench_methods.py``; prints one JSON line.

``python bench/_method_run.py DATA METHOD [--barrier DIR --peers N] [--extras] [--profile]``

The vision methods take their tracks from the images (the front end runs inside the filter
loop). ``--barrier``: after loading, wait until ``N`` runs are ready, so parallel runs overlap.
Threads per numerical library: ``SVAINS_THREADS`` (default 1), applied before any import.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np

from svains.threads import limit_threads


def _stages(src: object, wall_s: float) -> dict[str, float]:
    """Mean ms per stereo frame: image wait, front end and its stages, and the rest (IMU
    propagation, vision update, other sensors, set-up) from the run's wall time."""
    load = np.asarray(src.load_ms)  # type: ignore[attr-defined]
    fe = np.asarray(src.frontend_ms)  # type: ignore[attr-defined]
    n = max(fe.size, 1)
    out = {"png_wait": float(load.mean()), "frontend": float(fe.mean())}
    for key in ("rectify", "track", "detect", "stereo", "ransac"):
        out[f"  {key}"] = float(np.mean([d.get(key, 0.0) for d in src.stage_ms]))  # type: ignore[attr-defined]
    out["filter+rest"] = wall_s * 1e3 / n - out["png_wait"] - out["frontend"]
    out["total"] = wall_s * 1e3 / n
    return out


class _Replay:
    """Tracks recorded from a front-end run, served again (filter-only timing)."""

    kind = "images"
    pixel_noise_std = 1.0

    def __init__(self, rig: object, tracks: dict[int, object]) -> None:
        self.rig = rig
        self._tracks = tracks
        self._times = np.array(sorted(tracks), np.int64)

    def frame_times(self) -> np.ndarray:
        return self._times

    def tracks_at(self, t_ns: int, motion_prior: object = None) -> object:
        return self._tracks.get(int(t_ns))


def _filter_replay(ds: object, opts: object, tracks: dict[int, object]) -> dict[str, float]:
    """The filter side alone (IMU propagation, other sensors, vision update, runner loop) on
    the recorded tracks: CPU ms per frame of this process."""
    import svains.navigation.vision_pixels as vp
    from svains.evaluation.run import run_method
    from svains.navigation.vision_sources import rig_from_dataset

    make = vp.make_source
    src = _Replay(rig_from_dataset(ds), tracks)  # type: ignore[arg-type]
    vp.make_source = lambda *a, **k: src  # type: ignore[assignment]
    try:
        c0, w0 = time.process_time(), time.perf_counter()
        run_method(ds, "3d", opts)  # type: ignore[arg-type]
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    finally:
        vp.make_source = make  # type: ignore[assignment]
    n = max(len(tracks), 1)
    return {"replay_cpu_ms": cpu * 1e3 / n, "replay_wall_ms": wall * 1e3 / n}


def _wait(barrier: Path, peers: int) -> None:
    barrier.mkdir(parents=True, exist_ok=True)
    (barrier / f"ready-{os.getpid()}").touch()
    t0 = time.perf_counter()
    while len(list(barrier.glob("ready-*"))) < peers and time.perf_counter() - t0 < 120:
        time.sleep(0.005)


def run_one(args: argparse.Namespace) -> dict[str, object]:
    from dataclasses import replace

    import svains.navigation.vision_sources as vs
    from svains.datasets.loader import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.options import InitOptions, RunOptions
    from svains.navigation.vision import tune_run_options

    sources: list[vs.ImageTrackSource] = []
    recorded: dict[int, object] = {}
    init, tracks_at = vs.ImageTrackSource.__init__, vs.ImageTrackSource.tracks_at

    def _init(self: vs.ImageTrackSource, *a: object, **k: object) -> None:
        init(self, *a, **k)  # type: ignore[arg-type]
        sources.append(self)

    def _tracks_at(self: vs.ImageTrackSource, t_ns: int, motion_prior: object = None) -> object:
        tr = tracks_at(self, t_ns, motion_prior)  # type: ignore[arg-type]
        recorded[int(t_ns)] = tr
        return tr

    vs.ImageTrackSource.__init__ = _init  # type: ignore[method-assign]
    vs.ImageTrackSource.tracks_at = _tracks_at  # type: ignore[assignment,method-assign]
    ds = load_dataset(args.data)
    mo = {"source": "images", "rotation": "imu"} if args.method != "ins" else {}
    opts = RunOptions(model="biased", init=InitOptions(mode="groundtruth"), method_options=mo)
    opts = tune_run_options(ds, args.method, opts)
    if args.barrier is not None:
        _wait(Path(args.barrier), args.peers)
    load_avg = os.getloadavg()[0]
    prof = cProfile.Profile(time.thread_time) if args.profile else None
    c0 = time.process_time()
    if prof is not None:
        prof.enable()
    rep = run_method(ds, args.method, opts).report
    if prof is not None:
        prof.disable()
    out: dict[str, object] = {
        "method": args.method, "wall_s": rep["wall_s"], "rtf": rep["realtime_factor"],
        "cpu_s": time.process_time() - c0, "load_avg": load_avg,
        "rmse_m": rep.get("position_rmse_m"), "data_s": rep["data_duration_s"],
    }  # fmt: skip
    if sources:
        out["frames"] = len(sources[-1].frontend_ms)
        out["stages_ms"] = _stages(sources[-1], float(rep["wall_s"]))
        out["frontend_status"] = rep.get("vision", {}).get("frontend_status")
    if prof is not None:
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(40)
        out["profile"] = buf.getvalue()
    vs.ImageTrackSource.__init__ = init  # type: ignore[method-assign]
    vs.ImageTrackSource.tracks_at = tracks_at  # type: ignore[method-assign]
    if args.extras and args.method == "3d":
        prior_on = bool(opts.method_options.get("motion_prior", False))
        other = replace(opts, method_options={**opts.method_options, "motion_prior": not prior_on})
        out["other_prior"] = {
            "motion_prior": not prior_on,
            "rmse_m": run_method(ds, "3d", other).report.get("position_rmse_m"),
        }
        out.update(_filter_replay(ds, opts, dict(recorded)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", type=Path)
    ap.add_argument("method")
    ap.add_argument("--barrier", default=None)
    ap.add_argument("--peers", type=int, default=1)
    ap.add_argument("--extras", action="store_true")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    with limit_threads(None):
        res = run_one(args)
    sys.stdout.write(json.dumps(res) + "\n")


if __name__ == "__main__":
    main()
