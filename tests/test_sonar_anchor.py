"""The start's height from the sonar when no sensor fixed the start's position."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.evaluation.run import run_method
from svains.models.sonar import sonar_range
from svains.navigation.options import InitOptions, RunOptions
from svains.navigation.sonar_anchor import anchor_height
from svains.sensors.types import SonarCalib
from svains.sim import SimConfig, simulate

G_W = np.array([0.0, 0.0, -9.81])
DOWN = np.diag([1.0, -1.0, -1.0, 1.0])  # sonar +z along the body's -z (looking down)


def _state(height: float) -> np.ndarray:
    x = np.zeros(16)
    x[2] = height
    x[6] = 1.0  # level
    return x


def test_the_first_range_moves_a_local_start_to_the_height_it_measures() -> None:
    cal = SonarCalib(DOWN, 20.0, 0.01, 0.0)
    P = np.eye(15) * 0.1**2
    x = _state(0.0)  # the local origin, while the sonar sees 2.8 m of air
    got = anchor_height(x, P, None, cal, G_W, 2.8)
    assert got is not None
    moved, shift = got
    assert shift == pytest.approx(2.8)
    assert sonar_range(moved[None], cal.T_B_S, G_W, 0.0)[0, 0] == pytest.approx(2.8)
    # a range within 3 standard deviations is the ordinary update's
    assert anchor_height(_state(2.75), P, None, cal, G_W, 2.8) is None
    # a beam along the ground says nothing of the height
    sideways = SonarCalib(np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]]),
                          20.0, 0.01, 0.0)  # fmt: skip
    assert anchor_height(x, P, None, sideways, G_W, 2.8) is None


def test_a_vision_start_without_gps_fuses_the_sonar(tmp_path: Path) -> None:
    """A user's probe: after a vision start at height 0 the village's sonar (the MAV 2 m up)
    was refused 600 times of 600, silently."""
    cfg = SimConfig()
    cfg = replace(cfg, duration_s=8.0, seed=2,
                  camera=replace(cfg.camera, rate_hz=5.0, render_images=False))  # fmt: skip
    root = simulate(cfg, tmp_path / "ds")
    opts = RunOptions(init=InitOptions(mode="vision"), use_gps=False)
    res = run_method(load_dataset(root), "3d", opts)
    r = res.report
    assert r["init"]["height_from_sonar_m"] == pytest.approx(2.0, abs=0.3)
    sonar = r["measurements"]["sonar"]
    assert sonar["rejected"] <= 2 and sonar["fused"] >= 70
    # One no-echo reading among the first ranges (a user's probe: it set the height for the
    # whole run, 599 of 600 ranges refused): the median of the first five is taken.
    csv = root / "mav0/sonar0/data.csv"
    lines = csv.read_text().splitlines()
    head, first = lines[0], lines[1:]
    for j, ln in enumerate(first):  # the first two fused after the start (10 Hz of 20 Hz)
        if 50_000_000 < int(ln.split(",")[0]) - int(res.t_ns[0]) <= 200_000_000:
            first[j] = ",".join([ln.split(",")[0], "5.0"])
    csv.write_text("\n".join([head, *first]) + "\n")
    bad = run_method(load_dataset(root), "3d", opts).report
    assert bad["init"]["height_from_sonar_m"] == pytest.approx(r["init"]["height_from_sonar_m"],
                                                               abs=0.05)  # fmt: skip
    assert bad["measurements"]["sonar"]["fused"] >= sonar["fused"] - 2
    assert bad["ate_rmse_m"] == pytest.approx(r["ate_rmse_m"], rel=0.05)
