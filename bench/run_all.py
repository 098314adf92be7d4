"""Run every benchmark script in this folder and print their figures (``make bench``).

Each benchmark is a plain script printing its own measurements; this runner only calls them in
turn so one command reproduces every timing figure quoted in the README.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# Listed explicitly so the README and ``make bench`` agree on what is measured.
SCRIPTS: list[str] = [
    "bench_datasets.py",
    "bench_convert.py",
    "bench_filter.py",
    "bench_methods.py",
    "bench_frontend.py",
    "eval_frontend_sim.py",
    "bench_egomotion_cov.py",
    "euroc_rotation_check.py",
    "paper_ordering.py",
    "tc_noise_scan.py",
    "batch_scaling.py",
    "nees_blocks.py",
    "bench_render.py",
    "faults.py",
]


def main() -> int:
    failed = 0
    for name in SCRIPTS:
        print(f"=== {name}", flush=True)
        result = subprocess.run([sys.executable, str(HERE / name)], check=False)
        failed += result.returncode != 0
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
