"""Position-only GPS and no magnetometer: in-flight ``--init vision`` starts at several times
with the GPS velocities dropped (as a ROS ``NavSatFix`` gives the fixes), against the same
starts with them.

Each start holds a local frame until the GPS gives the heading: the fixes' path
(``navigation.heading_wait.FixPathHeading``) without velocities, the velocities' check with
them. Prints the turn found (and its standard deviation), when, and the run's ATE (m), NEES
(9 dof) and final error (m) either way.

    python bench/position_only_gps.py [../shared/data/kitti_raw_0926_41s]
        [--starts 0,7,14,18,25] [--method 3d]
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.run import run_method
from svains.navigation.options import InitOptions, RunConfig


def position_only(ds: Dataset) -> Dataset:
    """The data set with its GPS velocities dropped."""
    if ds.gps is None:
        raise SystemExit("the data set has no GPS")
    return replace(ds, gps=ds.gps.position_only())


def _cells(report: dict) -> str:
    init = report["init"]
    if "heading_turn_deg" in init:
        turn = (f"{init['heading_turn_deg']:.1f}° ± {init['heading_std_deg']:.1f}° at "
                f"{init['heading_found_s']:.1f} s")
    else:
        turn = init.get("heading", "-")
    return (f"{turn} | {report['ate_rmse_m']:.3f} / {report['nees_mean']:.1f} / "
            f"{report['final_error_m']:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="../shared/data/kitti_raw_0926_41s")
    ap.add_argument("--starts", default="0,7,14,18,25", help="start times [s], comma-separated")
    ap.add_argument("--method", default="3d")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    ds = load_dataset(Path(args.data))
    pos = position_only(ds)
    print("| start [s] | position-only: turn | ATE [m] / NEES / final error [m] | with "
          "velocities: turn | ATE / NEES / final |")
    print("|---|---|---|---|---|")
    for start in (float(s) for s in args.starts.split(",")):
        config = RunConfig(method=args.method, use_mag=False, init=InitOptions(mode="vision"))
        config = replace(config, replay=replace(config.replay, start_s=start))
        a = run_method(pos, args.method, config).report
        b = run_method(ds, args.method, config).report
        print(f"| {start:g} | {_cells(a)} | {_cells(b)} |", flush=True)


if __name__ == "__main__":
    main()
