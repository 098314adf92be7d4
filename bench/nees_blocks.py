"""Which states make a campaign's NEES: position, velocity and attitude NEES (3 dof each) over
time, averaged over the first runs of a batch spec, beside the vehicle's heading.

The campaign's ``summary.md`` tests the 9-dof NEES; this splits it (each block against its own
3x3 covariance, so the blocks do not add up to the whole). Consistent blocks average 3.

    python bench/nees_blocks.py [SPEC] [--runs 8] [--window 5]
      (default SPEC: bench/specs/nees_village_3d.yaml; its first source, config and method)
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from svains.batch import Task, load_spec
from svains.batch.settings import run_options_from_settings
from svains.batch.task import task_dataset
from svains.evaluation.accuracy import state_errors
from svains.evaluation.run import errors_alignment_for, run_method
from svains.replay import resolve_config
from svains.replay.groundtruth import interpolate_groundtruth, nees_of

HERE = Path(__file__).resolve().parent
BLOCKS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9)}


def block_nees(task: Task) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``t_ns`` (K,), block NEES (3, K) and heading (K,) [rad, about z] of one run."""
    with tempfile.TemporaryDirectory() as tmp:
        ds = task_dataset(task, Path(tmp))
        opts = resolve_config(ds, replace(run_options_from_settings(task.settings),
                                          method=task.method))
        result = run_method(ds, task.method, opts)
        errs = state_errors(result.t_ns, result.x, result.P9, ds.groundtruth,
                            errors_alignment_for(result))  # fmt: skip
        assert errs is not None and ds.groundtruth is not None
        nees = np.stack([nees_of(errs.e[:, s], errs.P9[:, s, s]) for s in BLOCKS.values()])
        q = interpolate_groundtruth(ds.groundtruth, errs.t_ns)[3]
        yaw = np.unwrap(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]),
                                   1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))  # fmt: skip
        return errs.t_ns, nees, yaw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", type=Path, default=HERE / "specs" / "nees_village_3d.yaml")
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--window", type=float, default=5.0, help="averaging window [s]")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    tasks = load_spec(args.spec).tasks()
    first = tasks[0]
    same = [t for t in tasks if (t.source, t.config, t.method) ==
            (first.source, first.config, first.method)][: args.runs]  # fmt: skip
    with ProcessPoolExecutor(max_workers=os.cpu_count()) as pool:
        runs = list(pool.map(block_nees, same))
    common = runs[0][0]
    for t, _, _ in runs[1:]:
        common = np.intersect1d(common, t)
    nees = np.mean([n[:, np.searchsorted(t, common)] for t, n, _ in runs], axis=0)  # (3, K)
    yaw = runs[0][2][np.searchsorted(runs[0][0], common)]
    t_s = (common - common[0]) * 1e-9
    print(f"{first.source}/{first.config}/{first.method}: block NEES (3 dof each, consistent: 3) "
          f"averaged over {len(runs)} runs; heading of the first run")
    print("window [s]   " + "  ".join(f"{b:>8s}" for b in BLOCKS) + "  heading [deg]")
    for a in np.arange(0.0, t_s[-1], args.window):
        s = (t_s >= a) & (t_s < a + args.window)
        cells = "  ".join(f"{nees[i, s].mean():8.2f}" for i in range(len(BLOCKS)))
        print(f"{a:4.0f}-{a + args.window:<4.0f}    {cells}  {np.degrees(yaw[s].mean()):10.1f}")
    print("whole run    " + "  ".join(f"{nees[i].mean():8.2f}" for i in range(len(BLOCKS))))


if __name__ == "__main__":
    main()
