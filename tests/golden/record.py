"""Record ``tests/golden/*.npz`` from the current run entry (run once, on purpose).

Usage: ``.venv/bin/python tests/golden/record.py`` (one thread per numerical library, as the tests
and svains run by default: ``SVAINS_THREADS`` unset or 1).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _golden_cases import CASES, GOLDEN_DIR, run_case, summarise


def main() -> None:
    rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                         check=True, cwd=GOLDEN_DIR).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            res = run_case(case, Path(tmp))
            arrays = summarise(res.t_ns, res.x, res.P9, res.report)
            np.savez_compressed(GOLDEN_DIR / f"{case.name}.npz", source_commit=rev, **arrays)
            print(case.name, len(res.t_ns), arrays["counts"].tolist())


if __name__ == "__main__":
    main()
