"""Issue 27's done-when figures from a finished ``bench/specs/time_offset_sim.yaml`` campaign.

    svains batch bench/specs/time_offset_sim.yaml --out TO
    python bench/time_offset.py TO [--after 20]

Per rate (20 Hz, 5 Hz), over the `estimate` runs of every offset and seed:

- the largest |estimate - truth| (ms) from ``--after`` s on (``report.json``'s
  ``vision.time_offset_history``, one entry per 0.2 s), per offset and overall;
- the offset's NEES ``(estimate - truth)² / σ²`` averaged over the N runs at each 0.5 s from
  ``--after`` s on, against the two-sided 95 % band of a chi-square with N dof over N: the
  share of those instants inside the band and the time average;
- the ATE of each `estimate` run over the ATE of the run given the true offset: the same
  scenario and seed (the same data) with a Kalibr camchain that states the true
  ``timeshift_cam_imu``, so the stamps are moved back by the calibration and the offset is not
  estimated (the `fixed` config's settings). Those reference runs are made here (``--jobs``
  processes) and kept in ``OUT/reference/`` (``--redo`` makes them again); on the 0 ms scenarios
  the `fixed` run is the reference itself. Worst, median and count above 1.10; and the `fixed`
  runs' ATE on the shifted stamps (what an unestimated offset costs).

The NEES band: the five offsets of one seed share the captures and the noise (only the stamps
differ), and their offset errors correlate (0.86-1.00 at 20 Hz), so the 25 runs of a rate are
5 independent draws, not 25. The test is per offset: the mean over its 5 seeds against the
95 % band of a chi-square with 5 dof over 5, at every instant; the pooled 25-run mean is printed
too, against the 25-dof band it would have if the runs were independent.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from svains.batch.settings import run_options_from_settings
from svains.datasets.kalibr import write_camchain
from svains.datasets.loader import load_dataset
from svains.evaluation.compare import trajectory_metrics
from svains.evaluation.run import run_method
from svains.replay import resolve_config
from svains.sim import SimConfig, simulate


def _runs(out: Path) -> list[dict[str, Any]]:
    """Every finished run: its parameters (``result.json``) and its ``report.json``."""
    runs = []
    for d in sorted((out / "runs").iterdir()):
        marker, report = d / "result.json", d / "report.json"
        if not (marker.is_file() and report.is_file()):
            continue
        res = json.loads(marker.read_text())
        if res.get("status") != "ok":
            continue
        params = res.get("params", res)
        runs.append({"params": params, "report": json.loads(report.read_text())})
    return runs


def _truth_ms(params: dict[str, Any]) -> float:
    cam = params["data"].get("camera", {})
    return float(cam.get("timeshift_cam_imu", 0.0)) * 1e3


def _rate(params: dict[str, Any]) -> float:
    return float(params["data"]["camera"]["rate_hz"])


def _reference_ate(params: dict[str, Any]) -> float:
    """ATE (``ate_m``) of the `fixed` run's settings on ``params``' scenario and seed, the
    data's calibration stating the true offset (stamps moved back by it)."""
    logging.basicConfig(level=logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        data = simulate(SimConfig.from_dict({**params["data"], "seed": params["seed"]}),
                        Path(tmp) / "data")
        ds = load_dataset(data)
        assert ds.cam0 is not None and ds.cam1 is not None
        chain = write_camchain(Path(tmp) / "camchain.yaml", (ds.cam0, ds.cam1),
                               None if ds.imu_calib is None else ds.imu_calib.T_B_S,
                               _truth_ms(params) * 1e-3)
        ds = load_dataset(data, calib=chain)
        options = resolve_config(
            ds, replace(run_options_from_settings(params["settings"]), method=params["method"])
        )
        result = run_method(ds, params["method"], options)
        return float(trajectory_metrics(result, ds, params["method"], False)["ate_m"])


def _references(out: Path, runs: list[dict[str, Any]], jobs: int, redo: bool) -> dict[
    tuple[float, float, int], float
]:
    """ATE given the true offset per (rate, offset, seed), from ``OUT/reference/`` or made."""
    folder = out / "reference"
    folder.mkdir(exist_ok=True)
    todo, refs = [], {}
    for r in runs:
        p = r["params"]
        if p["config"] != "fixed":
            continue
        key = (_rate(p), _truth_ms(p), int(p["seed"]))
        if key[1] == 0.0:  # the stamps are on the IMU clock: this run is the reference
            refs[key] = r["report"]["ate_m"]
            continue
        cached = folder / f"{p['source']}-s{p['seed']}.json"
        if cached.is_file() and not redo:
            refs[key] = json.loads(cached.read_text())["ate_m"]
        else:
            todo.append((key, cached, p))
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for (key, cached, _), ate in zip(todo, pool.map(_reference_ate, [t[2] for t in todo]),
                                         strict=True):
            cached.write_text(json.dumps({"ate_m": ate}))
            refs[key] = ate
    return refs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="campaign folder (svains batch --out)")
    ap.add_argument("--after", type=float, default=20.0, help="seconds before the checks")
    ap.add_argument("--jobs", type=int, default=2, help="processes for the reference runs")
    ap.add_argument("--redo", action="store_true", help="make the reference runs again")
    args = ap.parse_args()
    runs = _runs(args.out)
    refs = _references(args.out, runs, args.jobs, args.redo)
    by_rate: dict[float, list[dict[str, Any]]] = defaultdict(list)
    fixed_by: dict[tuple[float, float], list[float]] = defaultdict(list)
    for r in runs:
        p = r["params"]
        if p["config"] == "estimate":
            by_rate[_rate(p)].append(r)
        else:
            fixed_by[(_rate(p), _truth_ms(p))].append(r["report"]["ate_m"])
    for rate in sorted(by_rate, reverse=True):
        rs = by_rate[rate]
        grid = np.arange(args.after, 59.5 + 1e-9, 0.5)
        worst: dict[float, float] = defaultdict(float)
        nees_rows, ratios, finals = [], [], defaultdict(list)
        nees_by: dict[float, list[Any]] = defaultdict(list)
        ratio_by: dict[float, list[float]] = defaultdict(list)
        for r in rs:
            truth = _truth_ms(r["params"])
            v = r["report"]["vision"]
            h = v["time_offset_history"]
            t = np.asarray(h["t_s"]) - h["t_s"][0]
            e = np.asarray(h["value_ms"]) - truth
            s = np.asarray(h["std_ms"])
            late = t >= args.after
            worst[truth] = max(worst[truth], float(np.abs(e[late]).max()))
            finals[truth].append(v["time_offset_ms"] - truth)
            nees_rows.append(np.interp(grid, t, e * e / (s * s)))
            nees_by[truth].append(nees_rows[-1])
            base = refs.get((rate, truth, int(r["params"]["seed"])))
            if base:
                ratios.append(r["report"]["ate_m"] / base)
                ratio_by[truth].append(ratios[-1])
        n = len(rs)
        nees = np.mean(nees_rows, axis=0)
        lo, hi = chi2.ppf([0.025, 0.975], n) / n
        inside = float(np.mean((nees >= lo) & (nees <= hi)))
        print(f"## {rate:g} Hz: {n} runs")
        for truth in sorted(worst):
            f = np.asarray(finals[truth])
            print(f"  offset {truth:+6.1f} ms: max |error| after {args.after:g} s "
                  f"{worst[truth]:.2f} ms; final error mean {f.mean():+.2f}, max |.| "
                  f"{np.abs(f).max():.2f} ms")
        print(f"  all offsets: max |error| after {args.after:g} s {max(worst.values()):.2f} ms")
        for truth in sorted(nees_by):
            k = len(nees_by[truth])
            m = np.mean(nees_by[truth], axis=0)
            lo_k, hi_k = chi2.ppf([0.025, 0.975], k) / k
            q = np.asarray(ratio_by[truth])
            print(f"  offset {truth:+6.1f} ms: NEES (mean of {k} seeds) time average "
                  f"{m.mean():.2f}, range {m.min():.2f}-{m.max():.2f}, inside [{lo_k:.2f}, "
                  f"{hi_k:.2f}] at {100 * np.mean((m >= lo_k) & (m <= hi_k)):.0f} % of "
                  f"{grid.size} instants; ATE / ATE given the true offset: "
                  + ", ".join(f"{x:.3f}" for x in q))
        print(f"  pooled offset NEES (mean of {n} runs, not independent: see above) at "
              f"{grid.size} instants from {args.after:g} s: time average {nees.mean():.2f}, "
              f"range {nees.min():.2f}-{nees.max():.2f}, inside the {n}-dof band [{lo:.2f}, "
              f"{hi:.2f}] at {100 * inside:.0f} % of them")
        if ratios:
            q = np.asarray(ratios)
            print(f"  ATE / ATE given the true offset (same data): median {np.median(q):.3f}, "
                  f"max {q.max():.3f}, runs over 1.10: {int((q > 1.10).sum())} of {q.size}")
        for (rr, truth), ates in sorted(fixed_by.items()):
            if rr == rate:
                print(f"  fixed (offset not estimated) at {truth:+6.1f} ms: ATE median "
                      f"{np.median(ates):.3f} m (n={len(ates)})")


if __name__ == "__main__":
    main()
