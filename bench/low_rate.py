"""The paper's regime on a real MAV IMU: EuRoC V1_01 (real 200 Hz IMU, 145 s) with features
simulated along its ground truth at 5 Hz, GPS-denied, static start, every ``--strides`` frame
(S=1: 0.2 s apart, S=10: 2 s, S=25: 5 s). Each run is a fresh ``svains run`` process with the
defaults and ``--set vision.frame_stride=S`` only (issue 22's command); prints ATE, NEES and its
blocks (position, velocity, roll/pitch, yaw), frames fused and the exit status.

    python bench/low_rate.py [DATA] [--methods 3d tc lc] [--strides 1 10 25] [--jobs 2]
                             [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any


def run_one(data: str, method: str, stride: int, extra: list[str], root: Path) -> dict[str, Any]:
    """One ``svains run`` in its own process; its report (or its exit code and last line)."""
    out = root / f"{method}_S{stride}"
    cmd = [str(Path(sys.executable).with_name("svains")), "run", data, "--method", method,
           "--synthetic-features", "5", "--no-gps", "--no-mag", "--out", str(out), "--force",
           "--set", f"vision.frame_stride={stride}"]  # fmt: skip
    for kv in extra:
        cmd += ["--set", kv]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    row: dict[str, Any] = {"method": method, "stride": stride, "rc": proc.returncode}
    if proc.returncode != 0:
        lines = [s for s in proc.stderr.strip().splitlines() if s.strip()]
        row["error"] = lines[-1] if lines else "?"
        return row
    rep = json.loads((out / "report.json").read_text(encoding="utf-8"))
    vis = rep.get("vision", {})
    row.update(ate=rep.get("ate_rmse_m"), nees=rep.get("nees_mean"),
               blocks=rep.get("nees_blocks") or {}, fused=vis.get("frames_fused"),
               frames=vis.get("frames"), gated=vis.get("features_gated"),
               recoveries=len(rep.get("recovery", {}).get("events", [])))  # fmt: skip
    return row


def fmt(row: dict[str, Any]) -> str:
    if row["rc"] != 0:
        return f"| {row['method']} | {row['stride']} | exit {row['rc']}: {row['error'][:90]} |"
    b = row["blocks"]
    blocks = " / ".join(f"{b[k]:.1f}" if k in b else "-"
                        for k in ("position", "velocity", "roll_pitch", "yaw"))  # fmt: skip
    return (f"| {row['method']} | {row['stride']} | {row['ate']:.3f} | {row['nees']:.1f} | "
            f"{blocks} | {row['fused']}/{row['frames']} | {row['gated']} | "
            f"{row['recoveries']} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="../shared/data/euroc_v101_micro")
    ap.add_argument("--methods", nargs="+", default=["3d", "tc", "lc"])
    ap.add_argument("--strides", nargs="+", type=int, default=[1, 10, 25])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [(m, s) for m in args.methods for s in args.strides]
        with ThreadPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(lambda j: run_one(args.data, j[0], j[1], args.sets, Path(tmp)),
                                 jobs))  # fmt: skip
    print("| method | S | ATE [m] | NEES (9) | p / v / rp / yaw | frames fused | features "
          "gated | recoveries |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(fmt(row))


if __name__ == "__main__":
    main()
