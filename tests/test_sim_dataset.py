"""End to end: ``simulate()`` and ``svains simulate`` write a data set the reader reads back."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from conftest import TRAJECTORIES
from svains.cli.main import app
from svains.datasets import load_dataset
from svains.sim import SimConfig, simulate


@pytest.fixture(scope="module")
def features_only(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimConfig, Path]:
    cfg = SimConfig(duration_s=6.0, seed=4)
    cfg.camera.render_images = False
    root = simulate(cfg, tmp_path_factory.mktemp("sim") / "village_features")
    return cfg, root


def test_features_only_data_set_reads_back(features_only: tuple[SimConfig, Path]) -> None:
    cfg, root = features_only
    ds = load_dataset(root)
    np.testing.assert_array_equal(ds.gravity_W, [0.0, 0.0, -9.81])
    assert len(ds.imu.t_ns) == 601 and ds.imu.t_ns[0] == 0
    np.testing.assert_array_equal(ds.groundtruth.t_ns, ds.imu.t_ns)
    np.testing.assert_allclose(np.linalg.norm(ds.groundtruth.q_W_B_wxyz, axis=1), 1.0)
    np.testing.assert_allclose(ds.groundtruth.p_W_B[:, 2], 2.0, atol=1e-9)
    # noise densities in sensor.yaml are the per-sample stds over sqrt(rate)
    assert ds.imu_calib.gyro_noise_density == pytest.approx(cfg.imu.gyro_noise_std / 10.0)
    kin = ds.extras["kinematics"]
    res = ds.imu.gyro_B - kin["omega_B"]
    assert res.std() == pytest.approx(cfg.imu.gyro_noise_std, rel=0.1)
    # GPS at 1 Hz until the first outage at 15 s is beyond this 6 s flight
    assert len(ds.gps.t_ns) == 7
    assert len(ds.mag.t_ns) == 601 and len(ds.sonar.t_ns) == 121
    # features: 13 frames at 2 Hz, ids are landmark ids, pixels inside the image
    feats = ds.features
    assert len(feats.frame_times()) == 13
    lm = ds.extras["landmarks"]
    assert np.isin(feats.track_id, lm["id"]).all()
    assert ((feats.uv_left[:, 0] > -2) & (feats.uv_left[:, 0] < 754)).all()
    # rectified pair: rows agree up to pixel noise, disparity positive on average
    dv = feats.uv_left[:, 1] - feats.uv_right[:, 1]
    assert dv.std() == pytest.approx(np.sqrt(2) * cfg.camera.pixel_noise_std, rel=0.1)
    assert np.all(np.diff(feats.t_ns) >= 0)
    # cameras: ideal, rectified, same orientation, 0.11 m baseline along cam0's x axis
    assert ds.left is not None and len(ds.left) == 0
    np.testing.assert_array_equal(ds.cam0.distortion, 0.0)
    np.testing.assert_allclose(ds.cam0.T_B_C[:3, :3], ds.cam1.T_B_C[:3, :3])
    base = ds.cam0.T_B_C[:3, :3].T @ (ds.cam1.T_B_C[:3, 3] - ds.cam0.T_B_C[:3, 3])
    np.testing.assert_allclose(base, [0.11, 0.0, 0.0], atol=1e-12)


def test_true_features_match_landmark_projection(features_only: tuple[SimConfig, Path]) -> None:
    """features0 = projection of landmarks.csv through the ground-truth pose (+ pixel noise)."""
    cfg, root = features_only
    ds = load_dataset(root)
    lm = ds.extras["landmarks"]
    f, cu, cv = ds.cam0.intrinsics[0], ds.cam0.intrinsics[2], ds.cam0.intrinsics[3]
    t_frame = ds.features.frame_times()[5]
    k = int(np.searchsorted(ds.groundtruth.t_ns, t_frame))
    from svains.geometry.rotation import quat_to_rotmat

    R_W_B = quat_to_rotmat(ds.groundtruth.q_W_B_wxyz[k])
    T_B_C = ds.cam0.T_B_C
    R_W_C = R_W_B @ T_B_C[:3, :3]
    p_W_C = ds.groundtruth.p_W_B[k] + R_W_B @ T_B_C[:3, 3]
    rows = ds.features.t_ns == t_frame
    p_C = (lm["p_W_F"][ds.features.track_id[rows]] - p_W_C) @ R_W_C
    uv = np.column_stack([f * p_C[:, 0] / p_C[:, 2] + cu, f * p_C[:, 1] / p_C[:, 2] + cv])
    err = ds.features.uv_left[rows] - uv
    assert np.abs(err).max() < 6 * cfg.camera.pixel_noise_std
    assert err.std() == pytest.approx(cfg.camera.pixel_noise_std, rel=0.15)


def test_scenario_yaml_records_the_configuration(features_only: tuple[SimConfig, Path]) -> None:
    cfg, root = features_only
    text = (root / "mav0" / "state_groundtruth_estimate0" / "scenario.yaml").read_text()
    data = yaml.safe_load(text)
    generated = data.pop("generated")
    assert SimConfig.from_dict(data) == cfg
    assert generated["world"]["n_landmarks"] > 1000


def test_same_seed_same_data(features_only: tuple[SimConfig, Path], tmp_path: Path) -> None:
    cfg, root = features_only
    again = simulate(SimConfig.from_dict(cfg.to_dict()), tmp_path / "again")
    for rel in ("imu0/data.csv", "features0/data.csv", "gps0/data.csv"):
        assert (root / "mav0" / rel).read_bytes() == (again / "mav0" / rel).read_bytes()


def test_images_are_written_with_exposure_change(tmp_path: Path) -> None:
    cfg = SimConfig(duration_s=1.0, seed=1)
    cfg.camera.brightness_amplitude = 0.2
    cfg.camera.brightness_period_s = 2.0  # gains 1.0, 1.2, 1.0 at t = 0, 0.5, 1 s
    ds = load_dataset(simulate(cfg, tmp_path / "img"))
    assert len(ds.left) == 3 and len(ds.right) == 3
    np.testing.assert_array_equal(ds.left.t_ns, ds.features.frame_times())
    img = ds.left.load(0)
    assert img.shape == (480, 752) and img.std() > 20.0  # textured, not blank
    assert not np.array_equal(img, ds.right.load(0))
    means = [float(ds.left.load(k).mean()) for k in range(3)]
    assert means[1] / means[0] == pytest.approx(1.2, abs=0.06)
    assert means[2] / means[0] == pytest.approx(1.0, abs=0.06)


def test_cli_help_documents_every_option() -> None:
    result = CliRunner().invoke(app, ["simulate", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = re.sub(r"\x1b\[[0-9;]*m", "", result.output)
    for opt in ("--scenario", "--out", "--duration", "--seed", "--camera-rate", "--no-images",
                "--config", "--trajectory", "--imu-preset"):
        assert opt in text, opt


@pytest.mark.realdata  # a trajectory of ../shared/data/trajectories
def test_cli_trajectory_scenario_and_info(tmp_path: Path) -> None:
    out = tmp_path / "traj"
    tum = TRAJECTORIES / "euroc_V2_02_medium_groundtruth.tum"
    runner = CliRunner()
    cfg_path = tmp_path / "sim.yaml"
    cfg_path.write_text("gps:\n  rate_hz: 2.0\nsonar:\n  noise_std: 0.01\n")
    result = runner.invoke(app, ["simulate", "--out", str(out), "--trajectory", str(tum),
                                 "--duration", "4", "--no-images", "--seed", "3", "--config",
                                 str(cfg_path), "--imu-preset", "adis16448"])
    assert result.exit_code == 0, result.output
    ds = load_dataset(out)
    assert len(ds.gps.t_ns) == 9 and ds.sonar_calib.noise_std == 0.01  # from --config
    assert ds.imu_calib.gyro_random_walk == pytest.approx(1.9393e-5)  # from --imu-preset
    assert len(ds.imu.t_ns) == 401 and len(ds.features.frame_times()) == 9
    assert len(ds.features.t_ns) > 100  # the EuRoC flight sees the village around it
    # the sonar is mounted along the body axis that points down (EuRoC's IMU x is up)
    assert len(ds.sonar.t_ns) > 70
    k = np.searchsorted(ds.groundtruth.t_ns, ds.sonar.t_ns)
    height = ds.groundtruth.p_W_B[k, 2]
    assert np.median(np.abs(ds.sonar.range_m - height)) < 0.15
    info = runner.invoke(app, ["info", str(out)], terminal_width=200)
    assert info.exit_code == 0, info.output
    for stream in ("imu0", "gps0", "mag0", "sonar0", "cam0", "cam1", "features0"):
        assert stream in info.output, stream
    assert "truth" in info.output


def test_cli_rejects_bad_config(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("camera:\n  rate_hz: 50\n")
    result = CliRunner().invoke(app, ["simulate", "--out", str(tmp_path / "x"), "--config",
                                      str(bad), "--no-images"])
    assert result.exit_code == 1  # a bad input file (2 is for the command line itself)
    assert "camera.rate_hz must be in (0, 20]" in result.output
