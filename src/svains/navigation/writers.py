"""Output files of a run: ``trajectory.tum``, ``states.csv``, ``report.json``.

Each file is written atomically (temporary name, then rename), ``report.json`` last: a folder
with a ``report.json`` holds a complete run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from svains.models.state import BIASED, PAPER, StateLayout
from svains.outputs import atomic_path, atomic_write_text

if TYPE_CHECKING:
    from svains.navigation.runner import RunResult

_STATE_NAMES = [
    "p_W_B_x", "p_W_B_y", "p_W_B_z", "v_W_B_x", "v_W_B_y", "v_W_B_z",
    "q_W_B_w", "q_W_B_x", "q_W_B_y", "q_W_B_z", "omega_B_x", "omega_B_y", "omega_B_z",
    "bg_B_x", "bg_B_y", "bg_B_z", "ba_B_x", "ba_B_y", "ba_B_z",
]  # fmt: skip
_STD_NAMES = [
    "std_p_x", "std_p_y", "std_p_z", "std_v_x", "std_v_y", "std_v_z",
    "std_theta_x", "std_theta_y", "std_theta_z", "std_omega_x", "std_omega_y", "std_omega_z",
    "std_bg_x", "std_bg_y", "std_bg_z", "std_ba_x", "std_ba_y", "std_ba_z",
]  # fmt: skip


def _json_default(o: object) -> object:
    return o.tolist() if hasattr(o, "tolist") else str(o)


def write_outputs(out_dir: Path, result: RunResult, layout: StateLayout | None = None) -> None:
    """Write the three files into ``out_dir`` (created if needed); ``layout`` defaults to the one
    whose state size matches ``result.x``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if layout is None:
        layout = BIASED if result.x.shape[-1] == BIASED.nx else PAPER
    x = result.x
    # A replaced run: its old report.json goes first, so old and new files never pass as one run.
    (out_dir / "report.json").unlink(missing_ok=True)
    with atomic_path(out_dir / "trajectory.tum") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("# t x y z qx qy qz qw\n")
        for t, xs in zip(result.t_ns, x, strict=True):
            # Seconds written from the integer nanoseconds: no float64 rounding of the time.
            vals = " ".join(f"{v:.9f}" for v in (*xs[0:3], *xs[7:10], xs[6]))
            fh.write(f"{int(t) // 1_000_000_000}.{int(t) % 1_000_000_000:09d} {vals}\n")
    header = ",".join(["t_ns", *_STATE_NAMES[: layout.nx], *_STD_NAMES[: layout.ndx]])
    with atomic_path(out_dir / "states.csv") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(header + "\n")
        for t, xs, ss in zip(result.t_ns, x, result.std, strict=True):
            fh.write(f"{int(t)}," + ",".join(f"{v:.9g}" for v in np.concatenate([xs, ss])) + "\n")
    atomic_write_text(
        out_dir / "report.json", json.dumps(result.report, indent=2, default=_json_default) + "\n"
    )
