"""One timed navigation run in its own process, for ``bench_methods.py``; prints one JSON line.

``python bench/_method_run.py DATA METHOD [--barrier DIR --peers N] [--rotation M] [--aided]
[--extras] [--profile]`` (``M``: the vision motion model, default the library's; ``--aided``:
GPS, magnetometer and sonar fused too, otherwise none, as ``svains run --no-gps --no-mag
--no-sonar``).

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
    """Mean ms per stereo frame: front end and its stages, and the rest (image decoding waits
    in the replay, IMU propagation, vision update, other sensors, set-up) from the run's wall
    time."""
    fe = np.asarray(src.frontend_ms)  # type: ignore[attr-defined]
    n = max(fe.size, 1)
    out = {"frontend": float(fe.mean())}
    for key in ("rectify", "track", "detect", "stereo", "ransac"):
        out[f"  {key}"] = float(np.mean([d.get(key, 0.0) for d in src.stage_ms]))  # type: ignore[attr-defined]
    out["filter+rest"] = wall_s * 1e3 / n - out["frontend"]
    out["total"] = wall_s * 1e3 / n
    return out


class _Replay:
    """Tracks recorded from a front-end run, served again (filter-only timing), each with the
    front end's reference frame after it (the clone window keeps the pose of that frame)."""

    kind = "images"
    pixel_noise_std = 1.0

    def __init__(self, rig: object, tracks: dict[int, tuple[object, int | None]]) -> None:
        self.rig = rig
        self._tracks = tracks
        self._reference_ns: int | None = None

    def push(self, *args: object) -> bool:
        return True

    def discard(self, t_ns: int) -> None:
        pass

    def reference_time_ns(self) -> int | None:
        return self._reference_ns

    def tracks_at(self, t_ns: int, motion_prior: object = None) -> object:
        tracks, self._reference_ns = self._tracks.get(int(t_ns), (None, self._reference_ns))
        return tracks


def _filter_replay(
    ds: object, opts: object, tracks: dict[int, tuple[object, int | None]]
) -> dict[str, float]:
    """The filter side alone (IMU propagation, other sensors, vision update, event loop) on
    the recorded tracks: main-thread CPU ms per frame (the replay still decodes the images,
    on its own thread, which is left out) and wall ms per frame."""
    from svains.evaluation.run import run_method
    from svains.navigation import navigator
    from svains.navigation.vision_sources import rig_from_calibrations

    make = navigator.Navigator._make_source
    src = _Replay(rig_from_calibrations(ds.cam0, ds.cam1), tracks)  # type: ignore[attr-defined]
    navigator.Navigator._make_source = lambda self, kind: src  # type: ignore[method-assign]
    try:
        c0, w0 = time.thread_time(), time.perf_counter()
        run_method(ds, "3d", opts)  # type: ignore[arg-type]
        cpu, wall = time.thread_time() - c0, time.perf_counter() - w0
    finally:
        navigator.Navigator._make_source = make  # type: ignore[method-assign]
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
    from svains.navigation.options import InitOptions, RunOptions, VisionOptions
    from svains.replay import resolve_config

    sources: list[vs.ImageFrames] = []
    recorded: dict[int, tuple[object, int | None]] = {}
    init, tracks_at = vs.ImageFrames.__init__, vs.ImageFrames.tracks_at

    def _init(self: vs.ImageFrames, *a: object, **k: object) -> None:
        init(self, *a, **k)  # type: ignore[arg-type]
        sources.append(self)

    def _tracks_at(self: vs.ImageFrames, t_ns: int, motion_prior: object = None) -> object:
        tr = tracks_at(self, t_ns, motion_prior)  # type: ignore[arg-type]
        recorded[int(t_ns)] = (tr, self.reference_time_ns())
        return tr

    vs.ImageFrames.__init__ = _init  # type: ignore[method-assign]
    vs.ImageFrames.tracks_at = _tracks_at  # type: ignore[assignment,method-assign]
    ds = load_dataset(args.data)
    opts = RunOptions(method=args.method, model="biased", init=InitOptions(mode="groundtruth"),
                      vision=VisionOptions(source="images",
                                           rotation=args.rotation or VisionOptions().rotation),
                      use_gps=args.aided, use_mag=args.aided, use_sonar=args.aided)
    opts = resolve_config(ds, opts)
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
        "method": args.method, "rotation": opts.vision.rotation, "wall_s": rep["wall_s"],
        "rtf": rep["realtime_factor"],
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
    vs.ImageFrames.__init__ = init  # type: ignore[method-assign]
    vs.ImageFrames.tracks_at = tracks_at  # type: ignore[method-assign]
    if args.extras and args.method == "3d":
        prior_on = opts.vision.motion_prior
        other = replace(opts, vision=replace(opts.vision, motion_prior=not prior_on))
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
    ap.add_argument("--rotation", default=None)
    ap.add_argument("--aided", action="store_true")
    ap.add_argument("--extras", action="store_true")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    with limit_threads(None):
        res = run_one(args)
    sys.stdout.write(json.dumps(res) + "\n")


if __name__ == "__main__":
    main()
