"""``examples/online.py`` runs: it feeds EuRoC micro measurement by measurement and prints the
pose at the camera rate."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "online.py"


@pytest.mark.slow
def test_online_example_prints_poses_at_the_camera_rate(euroc_micro: Path) -> None:
    out = subprocess.run([sys.executable, str(EXAMPLE), str(euroc_micro), "3.0"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    lines = [ln for ln in out.splitlines() if "p_W_B [m]" in ln]
    t = [float(ln.split()[0]) for ln in lines]
    # 20 Hz from the start (static init backfills it) to 3 s: about 60 poses, 50 ms apart.
    assert 55 <= len(lines) <= 62
    steps = [b - a for a, b in itertools.pairwise(t[1:-1])]
    assert all(abs(dt - 0.05) < 0.006 for dt in steps)
    # The MAV sits still: every position within 5 cm of the start.
    xyz = [[float(v) for v in re.findall(r"p_W_B \[m\] (\S+) (\S+) (\S+)", ln)[0]]
           for ln in lines]
    assert max(abs(c) for p in xyz for c in p) < 0.05
    assert re.search(r"(\d+) stereo frames fused", out) and " 0 stereo frames" not in out
