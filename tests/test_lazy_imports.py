"""OpenCV is loaded only where images are processed: it starts its BLAS threads on load, and a
process that then forks workers (a campaign, a benchmark's process pool) leaves those workers
hung on the first OpenCV call that waits for the threads (the rendered-keyframes bench hung so
when the stereo check was imported with the replay)."""

from __future__ import annotations

import subprocess
import sys

MODULES = ("svains", "svains.replay", "svains.evaluation.run", "svains.cli.main",
           "svains.datasets.summary", "svains.navigation.navigator", "svains.batch")  # fmt: skip


def test_importing_the_library_and_the_command_line_loads_no_opencv() -> None:
    code = ("import sys\n"
            + "".join(f"import {m}\n" for m in MODULES)
            + "print(sorted(m for m in ('cv2', 'numba') if m in sys.modules))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()  # fmt: skip
    assert "cv2" not in out, out
