"""Image gaps in a recording: a few random spans of stereo pairs dropped, the same run with and
without a setting. Plain script (not a timed test).

Per seed, ``--gaps`` spans of ``--min-len``-``--max-len`` s start at uniform times inside the
recording (between ``--margin`` s from either end); their stereo pairs are removed (the IMU,
GPS and the rest stay), and ``--method`` runs through ``svains.evaluation.run`` with the
switches of ``svains run DATA --method M --images --init groundtruth`` and, per column, the
given ``--set`` items (none: the defaults). Prints the ATE (the report's ``ate_rmse_m``), the
NEES and the largest outage error (``outage_max_error_m``, when the data set has outages) per
seed and their means.

    python bench/image_gaps.py DATA [--method 3d] [--seeds 0-5] [--gaps 4] [--min-len 1.5]
        [--max-len 6] [--margin 5] --variant "NAME:KEY=VALUE[,KEY=VALUE]" ...

Example (the demo, ``svains demo --out D``; the motion prior of the image front end for frames
1 s apart, the default, against none):

    python bench/image_gaps.py D/dataset --seeds 1-6
        --variant "none:vision.motion_prior_after_s=null" --variant "default:"
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from faults import parse_seeds
from threadpoolctl import threadpool_limits

from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.run import run_method
from svains.replay import resolve_config

S = 1_000_000_000


def with_gaps(ds: Dataset, seed: int, n: int, lo_s: float, hi_s: float,
              margin_s: float) -> Dataset:  # fmt: skip
    """``ds`` with ``n`` random spans of stereo pairs removed (seeded)."""
    assert ds.left is not None and ds.right is not None
    rng = np.random.default_rng(seed)
    t0, t1 = ds.left.t_ns[0], ds.left.t_ns[-1]
    span_s = (t1 - t0) / S
    keep_l = np.ones(ds.left.t_ns.size, bool)
    keep_r = np.ones(ds.right.t_ns.size, bool)
    for _ in range(n):
        a = t0 + round(rng.uniform(margin_s, span_s - margin_s - hi_s) * S)
        b = a + round(rng.uniform(lo_s, hi_s) * S)
        keep_l &= ~((ds.left.t_ns >= a) & (ds.left.t_ns < b))
        keep_r &= ~((ds.right.t_ns >= a) & (ds.right.t_ns < b))
    return replace(ds, left=ds.left.rows(keep_l), right=ds.right.rows(keep_r))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data")
    ap.add_argument("--method", default="3d")
    ap.add_argument("--seeds", default="1-6")
    ap.add_argument("--gaps", type=int, default=4)
    ap.add_argument("--min-len", type=float, default=1.5)
    ap.add_argument("--max-len", type=float, default=6.0)
    ap.add_argument("--margin", type=float, default=5.0)
    ap.add_argument("--variant", action="append", required=True,
                    help="NAME:KEY=VALUE[,KEY=VALUE] (NAME: for the defaults)")
    args = ap.parse_args()
    variants = []
    for v in args.variant:
        name, _, sets = v.partition(":")
        variants.append((name, [s for s in sets.split(",") if s]))
    base = load_dataset(args.data)
    rows: dict[str, list[tuple[float, float, float]]] = {name: [] for name, _ in variants}
    head = " | ".join(f"{name}: ATE [m] / NEES / largest outage [m]" for name, _ in variants)
    print(f"| seed | {head} |")
    print("|---|" + "---|" * len(variants))
    for seed in parse_seeds(args.seeds):
        ds = with_gaps(base, seed, args.gaps, args.min_len, args.max_len, args.margin)
        cells = []
        for name, sets in variants:
            switches = {"method": args.method, "vision.source": "images",
                        "init.mode": "groundtruth"}  # fmt: skip
            config = resolve_config(ds, build_config(None, sets, switches))
            with threadpool_limits(limits=1):
                rep = run_method(ds, None, config).report
            out = max(rep.get("outage_max_error_m") or [float("nan")])
            rows[name].append((rep["ate_rmse_m"], rep["nees_mean"], out))
            cells.append(f"{rep['ate_rmse_m']:.3f} / {rep['nees_mean']:.2f} / {out:.3f}")
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)
    means = [" / ".join(f"{m:.3f}" for m in np.mean(rows[name], axis=0)) for name, _ in variants]
    print("| mean | " + " | ".join(means) + " |")


if __name__ == "__main__":
    main()
