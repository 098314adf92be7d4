"""Vision methods when frames arrive irregularly and far apart (0.05-7 s): the paper's
low-frame-rate regime on a flying vehicle. Plain script (not a timed test).

Part 1 (``real``): EuRoC V1_01 (real 200 Hz IMU, 145 s, ground truth) with stereo features
simulated along the ground truth at 20 Hz (``svains.replay.synthetic.with_synthetic_features``,
landmarks and pixel noise seeded by the seed). Per seed, a random subset of those frames is kept:
a walk from the first frame draws each next gap log-uniformly in ``[--min-gap, --max-gap]``
(default 0.05-7 s: median 0.59 s, mean 1.41 s, about 100 frames) and keeps the latest 20 Hz frame
at most that gap after the current one (so every spacing lies in the range, on the 50 ms grid),
until the gap would pass the last frame: the whole 145 s is covered. The gap walk has its own
random stream (``default_rng([FRAME_STREAM, seed])``), independent of the features' noise. The
data set's ``features`` stream is filtered in memory (``dataclasses.replace`` with a
``FeatureStream`` of the kept rows), then each method runs through ``svains.evaluation.run``
with ``svains run``'s defaults and ``--no-gps --no-mag`` (static start, the default init): the
same as ``svains run DATA --method M --synthetic-features 20 --no-gps --no-mag`` with only the
chosen frames. A run that raises is counted as stopped (its one-line error kept); one whose ATE
(``ate_rmse_m``, what ``svains run`` prints: se3-aligned for this local-frame start) exceeds
``--fail-ate`` (1 m) or is not finite counts as failed too. NEES is ``nees_mean`` (9 dof, after
the report's own alignment); its blocks are the report's ``nees_blocks`` when it has them,
otherwise position / velocity / attitude (3 dof each, each against its own 3x3 covariance:
consistent blocks average 3), computed here with ``svains.evaluation.accuracy.state_errors``
and the same alignment. ``--ins`` adds one INS run (it does not depend on the frames) as a
reference.

Part 2 (``sim``): ``svains simulate --trajectory`` flights along three real EuRoC trajectories
(``../shared/data/trajectories/``: V1_02_medium, V2_02_medium, MH_03_medium), ``--duration`` s
each, stereo at 2 Hz and 0.5 Hz (regular), run as a ``svains.batch`` campaign
(``bench/specs/irregular_frames_sim.yaml``: init from the true pose, no GPS, no magnetometer,
as ``paper_ordering.yaml``; the simulated sonar stays on, as there) on a local Dask cluster of
``--jobs`` workers. ``simulate`` renders PNG stereo images by default AND writes ``features0``
(true landmark projections with 0.5 px noise); the runs here read ``features0`` only
(``vision.source: features``), so the campaign uses feature-level simulation
(``camera.render_images: false``): rendering is not slow (about 0.1 s per stereo pair, 13 s
for a 60 s flight at 2 Hz) but would change nothing in these runs.
ATE is ``ate_m`` (``svains compare``'s: yaw+translation alignment for all methods, as
``paper_ordering.py``); prints the mean ATE per method and rate, and whether the paper's
ordering 3d <= lc <= vo holds by mean ATE (and by median: one diverged run moves a mean), twice:
over every pose each method writes (``ate_m``: the filters' 10 Hz poses, those between frames
carried by the IMU alone) and over the poses at the stereo frames only (``ate_frames_m``,
``svains.evaluation.compare.frame_rows``: the stamps ``vo`` writes).

    python bench/irregular_frames.py [--part {real,sim,both}] [--seeds 0-9]
        [--methods 3d tc lc vo] [--ins] [--min-gap 0.05] [--max-gap 7] [--rate 20]
        [--sim-seeds 0-2] [--rates 2 0.5] [--duration 60] [--jobs 2] [--verbose]
        [--set KEY=VALUE ...] [DATA]

``--set`` overrides run settings as ``svains run --set`` does (both parts). The defaults take
about 5 minutes on 2 busy cores (part 1 ~1.5 min for 40 runs, part 2 ~3 min for 72 runs). The
Dask workers of part 2 log the runs' warnings ("no vision fused for 2.1 s") on stderr.
"""

from __future__ import annotations

import argparse
import copy
import logging
import math
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from faults import parse_seeds  # bench/faults.py: "0-9", "0,1,5" or "3"
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from svains.batch import parse_spec, run_campaign
from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import Dataset, FeatureStream
from svains.evaluation.accuracy import state_errors
from svains.evaluation.run import errors_alignment_for, run_method
from svains.navigation.config_io import parse_setting
from svains.replay import resolve_config
from svains.replay.groundtruth import nees_of
from svains.replay.synthetic import with_synthetic_features

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
S = 1_000_000_000
FRAME_STREAM = 7  # first word of the gap walk's seed: a stream apart from the features' noise
VISION = ("3d", "tc", "lc", "vo")
BLOCKS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9)}
FLIGHTS = ("V1_02", "V2_02", "MH_03")
I64 = NDArray[np.int64]


# --- part 1: real IMU, irregular frames ------------------------------------------------------


def draw_frames(times: I64, rng: np.random.Generator, lo_s: float, hi_s: float) -> I64:
    """Indices into ``times`` (sorted frame stamps, ns) of a walk from the first frame: each next
    gap drawn log-uniformly in ``[lo_s, hi_s]``, the latest frame at most that far kept (the next
    one if none, across a hole in the stream), until the gap passes the last frame."""
    chosen = [0]
    while True:
        gap_s = math.exp(rng.uniform(math.log(lo_s), math.log(hi_s)))
        target = int(times[chosen[-1]]) + round(gap_s * S)
        if target > int(times[-1]):
            break
        j = int(np.searchsorted(times, target, side="right")) - 1
        chosen.append(max(j, chosen[-1] + 1))
    return np.asarray(chosen, np.int64)


def keep_frames(fs: FeatureStream, frame_t_ns: I64) -> FeatureStream:
    """``fs`` with only the rows of the frames stamped ``frame_t_ns``."""
    rows = np.isin(fs.t_ns, frame_t_ns)
    return FeatureStream(fs.t_ns[rows], fs.track_id[rows], fs.uv_left[rows], fs.uv_right[rows],
                         fs.pixel_noise_std)  # fmt: skip


@lru_cache(maxsize=2)
def irregular_dataset(data: str, seed: int, rate_hz: float, lo_s: float,
                      hi_s: float) -> tuple[Dataset, I64]:  # fmt: skip
    """The data set with features at ``rate_hz`` (seeded by ``seed``) thinned to the frames of
    :func:`draw_frames`, and the kept frame stamps (cached: a worker runs a seed's methods in
    a row)."""
    ds = with_synthetic_features(load_dataset(data), rate_hz=rate_hz, seed=seed)
    assert ds.features is not None
    times = ds.features.frame_times()
    kept = times[draw_frames(times, np.random.default_rng([FRAME_STREAM, seed]), lo_s, hi_s)]
    return replace(ds, features=keep_frames(ds.features, kept)), kept


@dataclass
class RealRun:
    """One run of part 1: ``seed`` (None: the seed-free INS reference), the kept frames' count
    and gaps [s], the report's figures, or ``error`` (the run raised)."""

    method: str
    seed: int | None
    frames: int = 0
    gaps_s: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # min, median, max
    ate: float = math.nan
    nees: float = math.nan
    blocks: dict[str, float] = field(default_factory=dict)
    fused: str = "-"
    recoveries: int = 0
    wall_s: float = math.nan
    error: str | None = None

    def failed(self, fail_ate: float) -> bool:
        return self.error is not None or not (self.ate <= fail_ate)


def nees_blocks(report: dict[str, Any], result: Any, ds: Dataset) -> dict[str, float]:
    """The report's ``nees_blocks`` if it has them, else the p / v / attitude block NEES means
    after the report's error alignment (empty without covariance)."""
    given = report.get("nees_blocks")
    if isinstance(given, dict) and given:
        return {str(k): float(v) for k, v in given.items() if isinstance(v, int | float)}
    if not result.has_covariance:
        return {}
    g = np.asarray(ds.gravity_W, float)
    errs = state_errors(result.t_ns, result.x, result.P9, ds.groundtruth,
                        errors_alignment_for(result), up_W=-g / np.linalg.norm(g))  # fmt: skip
    if errs is None:
        return {}
    return {k: float(np.mean(nees_of(errs.e[:, s], errs.P9[:, s, s]))) for k, s in BLOCKS.items()}


def number(row: dict[str, Any], key: str) -> float:
    """``row[key]`` as a float (NaN when absent or not a number)."""
    v = row.get(key)
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan


def report_figures(result: Any, ds: Dataset) -> tuple[float, float, dict[str, float], str]:
    """A run's ATE (``ate_rmse_m``), NEES (``nees_mean``), NEES blocks and frames fused
    ("fused/frames", "-" without vision) from its report."""
    rep = result.report
    vis = rep.get("vision") or {}
    fused = f"{vis.get('frames_fused')}/{vis['frames']}" if "frames" in vis else "-"
    return (number(rep, "ate_rmse_m"), number(rep, "nees_mean"), nees_blocks(rep, result, ds),
            fused)  # fmt: skip


def one_line(exc: BaseException) -> str:
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return f"{type(exc).__name__}: {lines[0] if lines else ''}"[:160]


def run_real(job: tuple[str, str, int | None, float, float, float, tuple[str, ...]]) -> RealRun:
    """Run ``method`` on seed ``seed``'s thinned data set (ins: on the data set as it is)."""
    data, method, seed, rate_hz, lo_s, hi_s, sets = job
    row = RealRun(method, seed)
    t0 = time.perf_counter()
    try:
        with threadpool_limits(limits=1):
            if seed is None:
                ds = load_dataset(data)
            else:
                ds, kept = irregular_dataset(data, seed, rate_hz, lo_s, hi_s)
                gaps = np.diff(kept) / S
                row.frames = int(kept.size)
                row.gaps_s = (float(gaps.min()), float(np.median(gaps)), float(gaps.max()))
            switches = {"method": method, "use_gps": False, "use_mag": False,
                        "replay.synthetic_features_hz": None if seed is None else rate_hz}
            config = build_config(None, list(sets), switches)
            result = run_method(ds, None, resolve_config(ds, config))
            row.ate, row.nees, row.blocks, row.fused = report_figures(result, ds)
            row.recoveries = len((result.report.get("recovery") or {}).get("events", []))
    except Exception as exc:  # a stopped run is a result of this bench
        row.error = one_line(exc)
    row.wall_s = time.perf_counter() - t0
    return row


SHORT = {"position": "p", "velocity": "v", "attitude": "θ", "roll_pitch": "rp", "yaw": "yaw"}


def fmt_blocks(blocks: dict[str, float]) -> str:
    """``p 3.1 / v 2.9 / rp 3.2 / yaw 2.7`` ("-": none)."""
    return " / ".join(f"{SHORT.get(k, k)} {v:.3g}" for k, v in blocks.items()) or "-"


def cell(value: float, spec: str) -> str:
    """``value`` formatted, "-" when NaN."""
    return "-" if math.isnan(value) else format(value, spec)


def stat(values: np.ndarray, fn: Any, spec: str = ".3f") -> str:
    """``fn(values)`` formatted, "-" when empty."""
    return format(float(fn(values)), spec) if values.size else "-"


def real_table(rows: list[RealRun], methods: list[str], fail_ate: float) -> None:
    """Per method: ATE mean / median / max over the runs that finished with a finite ATE, the
    stopped runs, the finished ones over ``fail_ate``, NEES and block means; then the errors."""
    print(f"\n| method | runs | mean ATE [m] | median ATE [m] | max ATE [m] | stopped | "
          f"ATE > {fail_ate:g} m | mean NEES (9) | mean NEES blocks |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m in methods:
        done = [r for r in rows if r.method == m and r.error is None]
        ate = np.array([r.ate for r in done if np.isfinite(r.ate)])
        nees = np.array([r.nees for r in done if np.isfinite(r.nees)])
        stopped = sum(r.method == m and r.error is not None for r in rows)
        over = sum(not r.ate <= fail_ate for r in done)
        keys = dict.fromkeys(k for r in done for k in r.blocks)
        blocks = {k: float(np.mean([r.blocks[k] for r in done if k in r.blocks])) for k in keys}
        print(f"| {m} | {len(done) + stopped} | {stat(ate, np.mean)} | {stat(ate, np.median)} | "
              f"{stat(ate, np.max)} | {stopped} | {over} | {stat(nees, np.mean, '.3g')} | "
              f"{fmt_blocks(blocks)} |")
    for e in sorted({f"{r.method}: {r.error}" for r in rows if r.error is not None}):
        print(f"- stopped: {e}")


def part_real(args: argparse.Namespace) -> None:
    methods = [m for m in args.methods if m != "ins"]
    sets = tuple(args.sets)
    jobs: list[tuple[str, str, int | None, float, float, float, tuple[str, ...]]] = [
        (args.data, m, seed, args.rate, args.min_gap, args.max_gap, sets)
        for seed in args.seeds for m in methods
    ]  # fmt: skip
    if args.ins:
        jobs.insert(0, (args.data, "ins", None, args.rate, args.min_gap, args.max_gap, sets))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(run_real, jobs))
    print(f"## Part 1: EuRoC V1_01 real IMU, features at {args.rate:g} Hz thinned to "
          f"log-uniform gaps {args.min_gap:g}-{args.max_gap:g} s, GPS-denied, no mag, static "
          f"start; seeds {','.join(map(str, args.seeds))} ({time.perf_counter() - t0:.0f} s)")
    if args.verbose:
        print("\n| seed | method | frames | gap min / median / max [s] | ATE [m] | NEES (9) | "
              "NEES blocks | frames fused | recoveries | wall [s] | status |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            gaps = " / ".join(f"{g:.2f}" for g in r.gaps_s) if r.frames else "-"
            status = r.error or ("ATE > limit" if r.failed(args.fail_ate) else "ok")
            print(f"| {'-' if r.seed is None else r.seed} | {r.method} | {r.frames or '-'} | "
                  f"{gaps} | {cell(r.ate, '.3f')} | {cell(r.nees, '.3g')} | "
                  f"{fmt_blocks(r.blocks)} | {r.fused} | {r.recoveries} | {r.wall_s:.1f} | "
                  f"{status} |")
    real_table(rows, (["ins"] if args.ins else []) + methods, args.fail_ate)


# --- part 2: simulated flights along real trajectories ---------------------------------------


def sim_spec(seeds: list[int], duration_s: float, rates: list[float],
             methods: list[str]) -> dict[str, Any]:  # fmt: skip
    """``bench/specs/irregular_frames_sim.yaml`` with one scenario per flight and rate, absolute
    trajectory paths, the duration, seeds and methods set."""
    raw = yaml.safe_load((HERE / "specs" / "irregular_frames_sim.yaml").read_text("utf-8"))
    scenarios: dict[str, Any] = {}
    for name, sc in raw["scenarios"].items():
        flight = name.rsplit("_", 1)[0]
        for rate in rates:
            s = copy.deepcopy(sc)
            s["trajectory.tum_path"] = str((REPO / s["trajectory.tum_path"]).resolve())
            s.update({"duration_s": duration_s, "camera.rate_hz": rate})
            scenarios[f"{flight}_{rate:g}hz"] = s
    raw.update(scenarios=scenarios, seeds=seeds, methods=methods)
    return dict(raw)


def part_sim(args: argparse.Namespace) -> None:
    methods = [m for m in ("vo", "lc", "tc", "3d") if m in args.methods]
    raw = sim_spec(args.sim_seeds, args.duration, args.rates, methods)
    raw["settings"].update(parse_setting(kv) for kv in args.sets)  # as ``svains run --set``
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_campaign(parse_spec(raw, HERE / "specs"), Path(tmp), n_workers=args.jobs,
                               sequential=args.jobs <= 1, figures=False)  # fmt: skip
    rows = summary.rows
    print(f"\n## Part 2: simulated flights along {', '.join(FLIGHTS)} ({args.duration:g} s, "
          f"feature-level), GPS-denied, no mag, from the true pose; seeds "
          f"{','.join(map(str, args.sim_seeds))} ({time.perf_counter() - t0:.0f} s)")

    def runs(method: str, rate: float, flight: str | None = None) -> list[dict[str, Any]]:
        return [r for r in rows if r["method"] == method and r["source"].endswith(f"_{rate:g}hz")
                and (flight is None or r["source"].startswith(flight))]  # fmt: skip

    def ate_of(rs: list[dict[str, Any]], key: str = "ate_m") -> np.ndarray:
        a = np.array([number(r, key) for r in rs if r["status"] == "ok"])
        return a[np.isfinite(a)]

    if args.verbose:
        print("\n| flight | rate [Hz] | " + " | ".join(f"{m} ATE [m]" for m in methods) + " |")
        print("|---|---|" + "---|" * len(methods))
        for flight in FLIGHTS:
            for rate in args.rates:
                cells = []
                for m in methods:
                    a = ate_of(runs(m, rate, flight))
                    cells.append(" ".join(f"{v:.2f}" for v in a) or "-")
                print(f"| {flight} | {rate:g} | " + " | ".join(cells) + " |")
    for key, what in (("ate_m", "every pose each method writes"),
                      ("ate_frames_m", "the poses at the stereo frames only, vo's stamps")):
        print(f"\nATE over {what} (`{key}`):")
        print("\n| rate [Hz] | " + " | ".join(f"{m} ATE mean (median) [m]" for m in methods)
              + " | failed runs | 3d <= lc <= vo by mean | by median |")  # fmt: skip
        print("|---|" + "---|" * len(methods) + "---|---|---|")
        for rate in args.rates:
            ates = {m: ate_of(runs(m, rate), key) for m in methods}
            failed = sum(r["status"] != "ok" for m in methods for r in runs(m, rate))
            order = []
            for fn in (np.mean, np.median):
                v = {m: float(fn(a)) if a.size else math.nan for m, a in ates.items()}
                holds = {"3d", "lc", "vo"} <= set(v) and v["3d"] <= v["lc"] <= v["vo"]
                order.append("yes" if holds else "no" if {"3d", "lc", "vo"} <= set(v) else "-")
            # Four decimals: at 2 Hz the methods lie within a few mm of one another.
            cells = [f"{stat(ates[m], np.mean, '.4f')} ({stat(ates[m], np.median, '.4f')})"
                     for m in methods]
            print(f"| {rate:g} | " + " | ".join(cells)
                  + f" | {failed} | {order[0]} | {order[1]} |")  # fmt: skip
    for r in rows:
        if r["status"] != "ok":
            print(f"- failed: {r['source']} seed {r['seed']} {r['method']}: {r.get('error')}")


# --- command line ----------------------------------------------------------------------------




def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(REPO.parent / "shared/data/euroc_v101_micro"))
    ap.add_argument("--part", choices=("real", "sim", "both"), default="both")
    ap.add_argument("--seeds", type=parse_seeds, default=list(range(10)),
                    help="part 1 seeds: 0-9, 0,3 or 4")
    ap.add_argument("--methods", nargs="+", default=list(VISION), choices=(*VISION, "ins"))
    ap.add_argument("--ins", action="store_true", help="part 1: also one INS reference run")
    ap.add_argument("--rate", type=float, default=20.0, help="part 1: feature rate before "
                    "thinning [Hz]")
    ap.add_argument("--min-gap", type=float, default=0.05, help="part 1: shortest gap [s]")
    ap.add_argument("--max-gap", type=float, default=7.0, help="part 1: longest gap [s]")
    ap.add_argument("--fail-ate", type=float, default=1.0, help="part 1: ATE [m] counted as "
                    "failed above")
    ap.add_argument("--sim-seeds", type=parse_seeds, default=[0, 1, 2],
                    help="part 2 seeds: 0-2, 0,3 or 4")
    ap.add_argument("--rates", type=float, nargs="+", default=[2.0, 0.5],
                    help="part 2 stereo rates [Hz]")
    ap.add_argument("--duration", type=float, default=60.0, help="part 2 flight length [s]")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes")
    ap.add_argument("--verbose", action="store_true", help="per-seed (part 1) and per-flight "
                    "(part 2) rows")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="run setting override, both parts (repeatable)")
    args = ap.parse_args()
    if "ins" in args.methods:
        args.ins = True
    logging.basicConfig(level=logging.ERROR)
    t0 = time.perf_counter()
    if args.part in ("real", "both"):
        part_real(args)
    if args.part in ("sim", "both"):
        part_sim(args)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
