"""A campaign's consistency test in the frame a local run's start defines (``nees_start_anchored``
beside the whole-run posyaw fit, which read a consistent GPS-denied ``ins`` 41x overconfident:
a probe)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from svains.batch import aggregate, parse_spec
from svains.batch.driver import data_groups
from svains.batch.store import read_nees, read_report, write_result
from svains.batch.task import run_group

SPEC: dict[str, Any] = {
    "name": "anchored",
    "scenarios": {"village8_rest": {
        "duration_s": 8.0, "camera.rate_hz": 5.0, "camera.render_images": False,
        "trajectory.stops": [[0.0, 3.0]],
        "imu.gyro_noise_std": 0.0016968, "imu.accel_noise_std": 0.02,
        "imu.gyro_random_walk": 1.9393e-5, "imu.accel_random_walk": 0.003}},
    "methods": ["ins", "3d"],
    "seeds": [0],
    "settings": {"fusion.use_gps": False, "fusion.use_mag": False, "fusion.use_sonar": False,
                 "vision.source": "features", "smoother.enabled": True},
}  # fmt: skip


def test_a_local_runs_start_anchored_nees_is_kept_and_tested(tmp_path: Path) -> None:
    spec = parse_spec(SPEC, tmp_path)
    out = tmp_path / "c"
    for group in data_groups(spec.tasks()):
        for task, result in zip(group, run_group(group), strict=True):
            write_result(out, task, result)
    aggregate(spec, out, figures=False)
    md = (out / "summary.md").read_text()
    for task in spec.tasks():
        rep = read_report(out, task)
        assert rep["errors_alignment"] == "posyaw"
        t_ns, nees = read_nees(out, task, "start-anchored")  # type: ignore[misc]
        assert len(t_ns) == rep["evaluated_states"]
        assert np.mean(nees) == pytest.approx(rep["nees_start_anchored"], rel=1e-8)
        assert f"| village8_rest | default | {task.method} start-anchored | 1 |" in md
        # the smoothed estimate's too
        _, nees_s = read_nees(out, task, "smoothed start-anchored")  # type: ignore[misc]
        assert np.mean(nees_s) == pytest.approx(rep["smoothed"]["nees_start_anchored"],
                                                rel=1e-8)  # fmt: skip
        assert f"| {task.method} smoothed start-anchored | 1 |" in md
