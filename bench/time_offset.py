"""Issue 27's done-when figures from a finished ``bench/specs/time_offset_sim.yaml`` campaign.

    svains batch bench/specs/time_offset_sim.yaml --out TO
    python bench/time_offset.py TO [--after 20]

Per rate (20 Hz, 5 Hz), over the `estimate` runs of every offset and seed:

- the largest |estimate - truth| (ms) from ``--after`` s on (``report.json``'s
  ``vision.time_offset_history``, one entry per 0.2 s), per offset and overall;
- the offset's NEES ``(estimate - truth)² / σ²`` averaged over the N runs at each 0.5 s from
  ``--after`` s on, against the two-sided 95 % band of a chi-square with N dof over N: the
  share of those instants inside the band and the time average;
- the ATE of each `estimate` run over the ATE of the `fixed` run of the same rate and seed on
  the 0 ms scenario (the same captures and noise, stamps on the IMU clock: the run given the
  true offset), worst and median, and the `fixed` runs' ATE on the shifted stamps (what an
  unestimated offset costs).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="campaign folder (svains batch --out)")
    ap.add_argument("--after", type=float, default=20.0, help="seconds before the checks")
    args = ap.parse_args()
    runs = _runs(args.out)
    fixed0 = {(_rate(r["params"]), r["params"]["seed"]): r["report"]["ate_m"]
              for r in runs if r["params"]["config"] == "fixed" and _truth_ms(r["params"]) == 0}
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
            base = fixed0.get((rate, r["params"]["seed"]))
            if base:
                ratios.append(r["report"]["ate_m"] / base)
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
        print(f"  offset NEES (mean of {n} runs, 1 dof each) at {grid.size} instants from "
              f"{args.after:g} s: time average {nees.mean():.2f}, range {nees.min():.2f}-"
              f"{nees.max():.2f}, inside the 95 % band [{lo:.2f}, {hi:.2f}] at "
              f"{100 * inside:.0f} % of them")
        if ratios:
            q = np.asarray(ratios)
            print(f"  ATE / ATE given the true offset (same seed): median {np.median(q):.3f}, "
                  f"max {q.max():.3f}, runs over 1.10: {int((q > 1.10).sum())} of {q.size}")
        for (rr, truth), ates in sorted(fixed_by.items()):
            if rr == rate:
                print(f"  fixed (offset not estimated) at {truth:+6.1f} ms: ATE median "
                      f"{np.median(ates):.3f} m (n={len(ates)})")


if __name__ == "__main__":
    main()
