"""A stereo baseline off by a factor: what a run does, and what the baseline's check says.

Plain script (not a timed test). For each factor, writes the data set's calibration as a Kalibr
camchain with cam1 moved along the baseline (``T_C0_C1``'s translation times the factor, the
rotation kept: the rectification is unchanged, every stereo distance scaled), runs
``svains run DATA --method M --calib CHAIN RUNARGS`` in a subprocess and prints the run's
ATE, final error and the report's ``vision.scale_check`` (the accelerometer's and the GPS's
factor of the images' distances, and whether each was warned) with the warning line.

    python bench/baseline_check.py ../shared/data/kitti_raw_0926_41s --factors 1 1.1 0.95 \\
        -- --images --no-mag --init gps
    python bench/baseline_check.py DATA --method lc --factors 1 1.05 -- --images --no-gps
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from svains.datasets import load_dataset
from svains.datasets.kalibr import write_camchain


def camchain(data: Path, factor: float, path: Path) -> Path:
    """``path``: ``data``'s cameras as a Kalibr camchain, cam1 ``factor`` times as far from
    cam0 along their baseline."""
    ds = load_dataset(data)
    if ds.cam0 is None or ds.cam1 is None:
        raise SystemExit(f"{data}: no stereo cameras")
    T_B_C0 = np.asarray(ds.cam0.T_B_C, float)
    T_C0_C1 = np.linalg.inv(T_B_C0) @ np.asarray(ds.cam1.T_B_C, float)
    T_C0_C1[:3, 3] *= factor
    T_B_S = None if ds.imu_calib is None else ds.imu_calib.T_B_S
    return write_camchain(path, (ds.cam0, replace(ds.cam1, T_B_C=T_B_C0 @ T_C0_C1)), T_B_S,
                          ds.cam0.timeshift_cam_imu_s)  # fmt: skip


def cell(d: dict[str, Any], key: str, std_key: str) -> str:
    v, s = d.get(key), d.get(std_key)
    if not isinstance(v, float):
        return "-"
    return f"{v:.4f} ± {s:.4f}" if isinstance(s, float) else f"{v:.4f}"


def main() -> None:
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--method", default="3d")
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 1.1, 0.95])
    args = ap.parse_args(argv[:cut])
    run_args = argv[cut + 1 :]
    svains = Path(sys.executable).with_name("svains")
    print(f"## {args.data.name}, `{args.method}` {' '.join(run_args)}\n")
    print("| baseline x | exit | ATE [m] | final [%] | accelerometer factor (fit) | warned | "
          "GPS factor (fit) | warned | warning |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for i, factor in enumerate(args.factors):
            chain = camchain(args.data, factor, Path(tmp) / f"camchain{i}.yaml")
            out = Path(tmp) / f"run{i}"
            p = subprocess.run([str(svains), "run", str(args.data), "--method", args.method,
                                "--calib", str(chain), "--out", str(out), *run_args],
                               capture_output=True, text=True)  # fmt: skip
            rep = (json.loads((out / "report.json").read_text(encoding="utf-8"))
                   if (out / "report.json").exists() else {})  # fmt: skip
            sc = (rep.get("vision") or {}).get("scale_check") or {}
            said = [ln.split(": ", 1)[-1] for ln in p.stderr.splitlines() if "baseline" in ln]
            fit = f" ({sc['fit']:.2f})" if isinstance(sc.get("fit"), float) else ""
            gfit = f" ({sc['gps_fit']:.2f})" if isinstance(sc.get("gps_fit"), float) else ""
            print(f"| {factor:g} | {p.returncode} | {rep.get('ate_rmse_m', float('nan')):.3f} | "
                  f"{rep.get('final_error_pct') or float('nan'):.2f} | "
                  f"{cell(sc, 'factor', 'factor_std')}{fit} | {sc.get('warned', '-')} | "
                  f"{cell(sc, 'gps_factor', 'gps_factor_std')}{gfit} | "
                  f"{sc.get('warned_gps', '-')} | {said[0][:150] if said else ''} |", flush=True)


if __name__ == "__main__":
    main()
