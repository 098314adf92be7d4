"""Regression cases recorded from the pre-Navigator batch runner (``tests/golden/*.npz``).

Each case is (data set, method, model, init mode, vision settings, duration). The data sets:
EuRoC micro (real IMU, synthetic 5 Hz features along the ground truth, or its 95 real stereo
pairs through the image front end) and a 30 s simulated village flight (features0 at 2 Hz, GPS,
magnetometer, sonar), generated from a seed.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

GOLDEN_DIR = Path(__file__).resolve().parent / "golden"
EUROC_MICRO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"
# Stored subsampling: x every X_STEP-th tick, P9 (upper triangle) every P_STEP-th tick.
X_STEP, P_STEP = 3, 10


@dataclass(frozen=True)
class Case:
    name: str
    data: str  # "euroc_synth", "euroc_images" or "village"
    method: str
    model: str = "biased"
    init: str = "static"
    duration_s: float | None = None
    vision: dict[str, Any] = field(default_factory=dict)


CASES = [
    Case("euroc_ins", "euroc_synth", "ins", duration_s=15.0),
    Case("euroc_ins_paper", "euroc_synth", "ins", model="paper", duration_s=15.0),
    Case("euroc_lc", "euroc_synth", "lc", duration_s=15.0),
    Case("euroc_tc", "euroc_synth", "tc", duration_s=15.0),
    Case("euroc_3d", "euroc_synth", "3d", duration_s=15.0),
    Case("euroc_images_3d", "euroc_images", "3d", duration_s=4.4,
         vision={"source": "images", "motion_prior": True}),
    Case("village_ins", "village", "ins", init="groundtruth"),
    Case("village_ins_gpsinit", "village", "ins", init="gps"),
    Case("village_lc", "village", "lc", init="groundtruth"),
    Case("village_tc", "village", "tc", init="groundtruth"),
    Case("village_3d", "village", "3d", init="groundtruth"),
    Case("village_3d_paper", "village", "3d", model="paper", init="groundtruth"),
    # Pose clones (the default motion model since the clone branch).
    Case("euroc_3d_clone", "euroc_synth", "3d", duration_s=15.0, vision={"rotation": "clone"}),
    Case("village_3d_clone", "village", "3d", init="groundtruth", vision={"rotation": "clone"}),
    Case("village_lc_clone", "village", "lc", init="groundtruth", vision={"rotation": "clone"}),
    Case("village_tc_clone", "village", "tc", init="groundtruth", vision={"rotation": "clone"}),
    Case("euroc_images_3d_clone", "euroc_images", "3d", duration_s=4.4,
         vision={"source": "images", "rotation": "clone"}),
]  # fmt: skip


def case_params(cases: list[Case]) -> list[Any]:
    """``cases`` as ``pytest.param``s named after the case; those on EuRoC micro (read from
    ``../shared/data``) marked ``realdata``."""
    import pytest

    return [pytest.param(c, id=c.name, marks=[] if c.data == "village" else pytest.mark.realdata)
            for c in cases]  # fmt: skip


def village_root(tmp: Path) -> Path:
    """The 30 s village flight (seed 7, feature level, no images), simulated once into ``tmp``."""
    from svains.sim.config import SimConfig
    from svains.sim.simulate import simulate

    root = tmp / "village30"
    if not (root / "mav0").is_dir():
        cfg = SimConfig(seed=7, duration_s=30.0)
        cfg.camera.render_images = False
        simulate(cfg, root)
    return root


def summarise(t_ns: Any, x: Any, P9: Any, report: dict[str, Any]) -> dict[str, np.ndarray]:
    """The stored arrays of one run."""
    iu = np.triu_indices(9)
    return {
        "t_ns": np.asarray(t_ns, np.int64),
        "x": np.asarray(x)[::X_STEP],
        "P9": np.asarray(P9)[::P_STEP][:, iu[0], iu[1]],
        "counts": np.array(sorted(
            (k, v["fused"], v["rejected"]) for k, v in report["measurements"].items()
        ), dtype=object).astype(str),
    }  # fmt: skip


def load_case_dataset(case: Case, tmp: Path) -> Any:
    """The case's data set (a ``Dataset``; loaded once per session and kind)."""
    return _load(case.data, village_root(tmp) if case.data == "village" else EUROC_MICRO)


@functools.lru_cache(maxsize=4)
def _load(kind: str, root: Path) -> Any:
    from svains.datasets import load_dataset

    ds = load_dataset(root)
    if kind == "euroc_synth":
        from svains.replay.synthetic import with_synthetic_features

        ds = with_synthetic_features(ds, rate_hz=5.0)
    return ds


def case_options(case: Case, ds: Any) -> Any:
    """The run configuration of ``case`` as ``svains run`` builds it (resolved against ``ds``)."""
    from svains.navigation.options import InitOptions, RunConfig, VisionOptions
    from svains.replay import resolve_config

    cfg = RunConfig(method=case.method, model=case.model,  # type: ignore[arg-type]
                    init=InitOptions(mode=case.init),  # type: ignore[arg-type]
                    duration_s=case.duration_s,
                    vision=VisionOptions(**{"rotation": "imu", **case.vision}))
    return resolve_config(ds, cfg)


def run_case(case: Case, tmp: Path) -> Any:
    """Replay ``case`` through the Navigator; returns its ``RunResult``."""
    from svains.replay import replay

    ds = load_case_dataset(case, tmp)
    return replay(ds, case_options(case, ds))


def record(names: list[str], tmp: Path) -> list[str]:
    """Re-record the golden cases ``names`` (all when empty) from the current code: one line
    per case, its fused/rejected counts before and after. ``source_commit`` is the commit the
    code was at (the working tree may differ: say so in the commit that stores them)."""
    import subprocess

    unknown = set(names) - {c.name for c in CASES}
    if unknown:
        raise SystemExit(f"no golden case named {', '.join(sorted(unknown))}")
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                          cwd=GOLDEN_DIR, check=False).stdout.strip()  # fmt: skip
    lines = []
    for case in CASES:
        if names and case.name not in names:
            continue
        res = run_case(case, tmp)
        arrays = summarise(res.t_ns, res.x, res.P9, res.report)
        path = GOLDEN_DIR / f"{case.name}.npz"
        before = np.load(path, allow_pickle=True)["counts"].tolist() if path.exists() else None
        np.savez_compressed(path, source_commit=np.array(head), **arrays)
        lines.append(f"{case.name}: counts {before} -> {arrays['counts'].tolist()}")
    return lines


if __name__ == "__main__":
    # Re-record after a change that is meant to move the goldens:
    #   python tests/_golden_cases.py [CASE ...]    (no names: every case)
    import sys
    import tempfile

    for line in record(sys.argv[1:], Path(tempfile.mkdtemp())):
        print(line)
