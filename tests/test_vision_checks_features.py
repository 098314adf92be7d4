"""The calibration checks on recorded features for ``tc``/``3d``: the tracks carry no
egomotion, so the checks take the front end's for their first frames (before, they judged
nothing: a rig turned 90° ran 804 m off with exit 0, a user's probe)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest

from conftest import TRAJECTORIES
from svains.datasets import load_dataset
from svains.evaluation.run import run_method
from svains.geometry.rotation import so3_exp
from svains.navigation.options import InitOptions, RunOptions


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s along EuRoC V1_02 (turning), recorded features at 10 Hz, no GPS."""
    from svains.sim.config import ImuConfig, SimConfig
    from svains.sim.simulate import simulate

    cfg = SimConfig(scenario="trajectory", duration_s=20.0, seed=1)
    cfg.trajectory.tum_path = str(TRAJECTORIES / "euroc_V1_02_medium_groundtruth.tum")
    cfg.imu = ImuConfig.preset("adis16448")
    cfg.camera.rate_hz = 10.0
    cfg.camera.render_images = False
    cfg.gps.enabled = cfg.mag.enabled = cfg.sonar.enabled = False
    return simulate(cfg, tmp_path_factory.mktemp("checks_features") / "v102")


@pytest.mark.realdata  # a trajectory of ../shared/data/trajectories
@pytest.mark.parametrize("turned_deg", [0.0, 90.0])
def test_a_rig_turned_on_the_body_is_told_from_recorded_features(
    flight: Path, turned_deg: float, caplog: pytest.LogCaptureFixture
) -> None:
    ds = load_dataset(flight)
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.radians(turned_deg) * np.array([0.0, 0.0, 1.0]))
    ds = dataclasses.replace(ds, cam0=dataclasses.replace(ds.cam0, T_B_C=T @ ds.cam0.T_B_C),
                             cam1=dataclasses.replace(ds.cam1, T_B_C=T @ ds.cam1.T_B_C))
    with caplog.at_level(logging.WARNING, logger="svains.navigation"):
        res = run_method(ds, "3d", RunOptions(init=InitOptions(mode="groundtruth"),
                                              use_gps=False, use_mag=False))  # fmt: skip
    rc = res.report["vision"]["rotation_check"]
    assert rc["frames"] >= 30
    checks = [r.getMessage() for r in caplog.records
              if r.name.endswith(("rotation_check", "scale_check"))]
    if turned_deg:
        assert rc["warned"] and rc["median_axis_deg"] > 45.0
        # one cause named: the scale check stands down once the mount is told
        assert len(checks) == 1 and "the camera turns about an axis" in checks[0]
    else:
        assert not rc["warned"] and rc["mount_error_deg"] < 0.5 and checks == []
