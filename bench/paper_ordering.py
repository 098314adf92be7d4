"""Does the paper's accuracy ordering (3d >= tc > lc > vo) hold? Ten seeds of the village flight.

The campaign is ``bench/specs/paper_ordering.yaml`` (``svains batch`` runs it alone and writes
``summary.md``); this script runs it through the batch library (local Dask cluster) and prints
what the spec's summary does not: the ATE of every method per seed (posyaw alignment for all
four, as ``svains compare`` does for runs started from the true pose; VO's se3-aligned ATE too),
the means, and how often each pair is ordered as the paper claims, by ATE and by final error.

    python bench/paper_ordering.py [--seeds 10] [--duration 60] [--rate 5] [--out DIR]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from svains.batch import parse_spec, run_campaign

HERE = Path(__file__).resolve().parent
METHODS = ("vo", "lc", "tc", "3d")
# Pairs (better, worse) as the paper orders them.
PAPER_PAIRS = (("3d", "tc"), ("tc", "lc"), ("lc", "vo"), ("3d", "vo"), ("tc", "vo"))


def spec_with(name: str, seeds: list[int], duration_s: float, rate_hz: float) -> dict[str, Any]:
    """``bench/specs/<name>.yaml`` with its scenario's seeds, duration and stereo rate set."""
    raw = yaml.safe_load((HERE / "specs" / f"{name}.yaml").read_text(encoding="utf-8"))
    raw["seeds"] = seeds
    for scenario in raw["scenarios"].values():
        scenario.update({"duration_s": duration_s, "camera.rate_hz": rate_hz})
    return dict(raw)


def campaign_rows(raw: dict[str, Any], out: Path | None) -> dict[tuple[Any, ...], Any]:
    """Run the campaign into ``out`` (a temporary folder if None); ``(seed, config, method) ->``
    its ``summary.csv`` row (a failed run has no report keys)."""
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_campaign(parse_spec(raw, HERE / "specs"), out or Path(tmp), figures=False)
    return {(int(r["seed"]), r["config"], r["method"]): r for r in summary.rows}


def value(row: dict[str, Any], key: str) -> float:
    v = row.get(key)
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else np.nan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=5.0, help="stereo rate [Hz]")
    ap.add_argument("--out", type=Path, default=None, help="campaign folder (default: temporary)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    t0 = time.perf_counter()
    rows = campaign_rows(spec_with("paper_ordering", list(range(args.seeds)), args.duration,
                                   args.rate), args.out)  # fmt: skip
    ate = np.array([[value(rows[s, "default", m], "ate_m") for m in METHODS]
                    for s in range(args.seeds)])  # fmt: skip
    final = np.array([[value(rows[s, "default", m], "final_error_pct_of_path") for m in METHODS]
                      for s in range(args.seeds)])  # fmt: skip
    # run_accuracy's ATE: se3 alignment (what remains when roll/pitch drift is aligned away),
    # with fewer degrees of freedom when a short flight makes se3 degenerate.
    vo = [rows[s, "default", "vo"] for s in range(args.seeds)]
    vo_se3 = np.array([value(r, "ate_rmse_m") for r in vo])
    for seed in range(args.seeds):
        row = "  ".join(f"{m} {ate[seed, j]:.3f}" for j, m in enumerate(METHODS))
        print(f"seed {seed}: ATE [m]  {row}  "
              f"(vo {vo[seed].get('alignment')}-aligned {vo_se3[seed]:.3f})")
    print(f"\n{args.seeds} seeds, {args.duration:.0f} s GPS-denied village, "
          f"stereo {args.rate:g} Hz ({time.perf_counter() - t0:.0f} s)")
    print("method  ATE mean [m]  ATE median [m]  final error mean [% path]")
    for j, m in enumerate(METHODS):
        print(f"{m:6s}  {np.mean(ate[:, j]):12.3f}  {np.median(ate[:, j]):14.3f}  "
              f"{np.mean(final[:, j]):10.2f}")
    print(f"vo with se3 alignment (roll/pitch drift aligned away): ATE mean {np.mean(vo_se3):.3f}")
    idx = {m: j for j, m in enumerate(METHODS)}
    for name, val in (("ATE", ate), ("final error", final)):
        print(f"paper's pair (better > worse): seeds where it holds by {name}")
        for a, b in PAPER_PAIRS:
            tie = np.isclose(val[:, idx[a]], val[:, idx[b]], rtol=1e-6)
            wins = int(np.sum((val[:, idx[a]] < val[:, idx[b]]) & ~tie))
            ties = int(np.sum(tie))
            print(f"  {a} > {b}: {wins}/{args.seeds}" + (f" (equal in {ties})" if ties else ""))
    for name, val in (("ATE", ate), ("final error", final)):
        order = sorted(METHODS, key=lambda m: np.mean(val[:, idx[m]]))
        print(f"ordering by mean {name} (best first): " + " , ".join(order))


if __name__ == "__main__":
    main()
