"""The typed run configuration through ``svains run``: YAML round trip, ``--set``, the effective
``OUT/config.yaml`` reproducing a run byte for byte, ``--start``, GPS outages, output files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from svains.cli.main import app
from svains.errors import ConfigError
from svains.navigation.config_io import from_dict, from_yaml, to_dict, to_yaml, with_settings
from svains.navigation.options import RunConfig, VisionOptions
from svains.sim import SimConfig, simulate


@pytest.fixture(scope="module")
def village_gps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 s village flight, stereo 5 Hz features only, GPS 1 Hz (no outage in the first 8 s)."""
    cfg = SimConfig()
    cfg = replace(cfg, duration_s=8.0, seed=4,
                  camera=replace(cfg.camera, rate_hz=5.0, render_images=False))
    return simulate(cfg, tmp_path_factory.mktemp("village") / "ds")


def _cli(args: list[str]) -> str:
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    return res.output


def test_yaml_round_trip_is_exact(tmp_path: Path) -> None:
    c = RunConfig(method="3d", duration_s=1.0 / 3.0, gps_outages=((1.5, 2.0),),
                  vision=VisionOptions(pixel_noise_std=0.1 + 0.2, lc_min_std=(1e-7, 3.3e-3)))
    path = tmp_path / "c.yaml"
    to_yaml(c, path, header="a comment")
    assert from_yaml(path) == c
    assert from_dict(yaml.safe_load(to_yaml(RunConfig()))) == RunConfig()
    assert to_dict(c)["gps_outages"] == [[1.5, 2.0]]


def test_bad_settings_name_their_key() -> None:
    c = RunConfig()
    with pytest.raises(ConfigError, match=r"filter\.max_predict_steps must be an integer"):
        with_settings(c, {"filter.max_predict_steps": "ten"})
    with pytest.raises(ConfigError, match=r"unknown configuration key 'noise\.gyro'"):
        with_settings(c, {"noise.gyro": 1.0})
    # a near miss names the key meant (a probe: a --config file listed its section's keys,
    # --set said nothing)
    with pytest.raises(ConfigError, match=r"unknown configuration key 'vision\.frame_strid'; "
                       r"did you mean 'vision\.frame_stride'\?"):  # fmt: skip
        with_settings(c, {"vision.frame_strid": 2})
    with pytest.raises(ConfigError, match=r"unknown configuration section 'nope'"):
        with_settings(c, {"nope.key": 1})
    with pytest.raises(ConfigError, match=r"init\.mode must be one of"):
        with_settings(c, {"init.mode": "flying"})
    assert with_settings(c, {"vision.lc_min_std": [0.1, 2]}).vision.lc_min_std == (0.1, 2.0)


@pytest.mark.parametrize(("setting", "value", "message"), [
    # Each accepted silently before (a user's probe, 2026-12-06): a hang, exit 0 with an ATE of
    # kilometres, or a crash after the whole run.
    ("output_period_s", "1e-9", r"output_period_s must be at least 0\.001 s"),
    ("filter.gate_probability", 0, r"filter\.gate_probability must be a probability in \[0\.5, "),
    # every update refused, the run diverged into a numerical error naming no key
    ("filter.gate_probability", 1e-4, r"filter\.gate_probability must be a probability in "
     r"\[0\.5, 1\) \(the share of consistent data its test passes\), got 0\.0001"),
    ("faults.bias_test_probability", 0.3, r"faults\.bias_test_probability must be a probability"),
    ("vision.feature_gate_probability", 1.5, r"vision\.feature_gate_probability must be a prob"),
    ("init.gt_attitude_std", 0, r"init\.gt_attitude_std must be positive"),
    ("init.gt_position_std", -1, r"init\.gt_position_std must be positive"),
    ("noise.gyro_noise_density", -1, r"noise\.gyro_noise_density must be positive"),
    ("noise.accel_noise_density", 0, r"noise\.accel_noise_density must be positive"),
    ("noise.white_scale", 0, r"noise\.white_scale must be positive"),
    ("noise.gyro_random_walk", -1e-5, r"noise\.gyro_random_walk must not be negative"),
    ("vision.pixel_noise_std", -2, r"vision\.pixel_noise_std must be positive"),
    ("vision.lc_min_std", [0.0, 1e-3], r"vision\.lc_min_std must be positive"),
    ("filter.alpha", 0, r"filter\.alpha must be positive"),
    ("filter.beta", -100, r"filter\.beta must not be negative"),
    ("filter.kappa", -50, r"filter\.kappa must be above -9"),
    ("gps_until_s", -1, r"gps_until_s must not be negative"),
    ("noise.white_scale", float("nan"), r"noise\.white_scale must be finite"),
    ("max_mag_rate_hz", float("inf"), r"max_mag_rate_hz must be finite"),
])  # fmt: skip
def test_numbers_out_of_their_range_are_refused_naming_the_key(
        setting: str, value: object, message: str) -> None:  # fmt: skip
    with pytest.raises(ConfigError, match=message):
        with_settings(RunConfig(), {setting: value})


def test_a_number_with_an_exponent_and_no_dot_is_a_number() -> None:
    """YAML 1.1 reads ``1e-3`` as a string; a float option takes it as the number."""
    from svains.navigation.config_io import parse_setting

    c = with_settings(RunConfig(), dict([parse_setting("output_period_s=2e-3"),
                                         parse_setting("noise.white_scale=1E+1")]))  # fmt: skip
    assert c.output_period_s == 2e-3 and c.noise.white_scale == 10.0
    with pytest.raises(ConfigError, match=r"filter\.max_predict_steps must be an integer"):
        with_settings(RunConfig(), dict([parse_setting("filter.max_predict_steps=1e3")]))


def test_rotation_has_one_default() -> None:
    assert VisionOptions().rotation == "clone" == RunConfig().vision.rotation


def test_effective_config_reproduces_the_run_byte_for_byte(village_gps: Path,
                                                           tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    _cli(["run", str(village_gps), "--method", "3d", "--init", "groundtruth", "--out", str(a),
          "--set", "vision.max_features=40", "--set", "filter.max_predict_steps=10",
          "--gps-outage", "2:3", "--start", "0.5"])
    text = (a / "config.yaml").read_text()
    assert text.startswith("# svains run configuration") and "git " in text
    cfg = from_yaml(a / "config.yaml")
    assert cfg.vision.source == "features" and cfg.vision.pixel_noise_std == 0.5
    assert cfg.filter.max_predict_steps == 10 and cfg.replay.start_s == 0.5
    _cli(["run", str(village_gps), "--config", str(a / "config.yaml"), "--out", str(b)])
    assert (a / "trajectory.tum").read_bytes() == (b / "trajectory.tum").read_bytes()
    assert (a / "config.yaml").read_text() == (b / "config.yaml").read_text()
    # A run made without --smooth is smoothed in place by re-running its own config (the
    # smoothing page's recipe): the forward estimate is the run's to the byte.
    _cli(["run", str(village_gps), "--config", str(b / "config.yaml"), "--smooth",
          "--out", str(b), "--force"])
    assert (a / "trajectory.tum").read_bytes() == (b / "trajectory.tum").read_bytes()
    assert (b / "trajectory_smoothed.tum").read_bytes() != (b / "trajectory.tum").read_bytes()
    tum = np.loadtxt(a / "trajectory.tum")
    t_imu0 = np.loadtxt(village_gps / "mav0" / "imu0" / "data.csv", delimiter=",")[0, 0] * 1e-9
    assert tum[0, 0] >= t_imu0 + 0.5  # --start skipped the first half second


def test_output_files_are_readable(village_gps: Path, tmp_path: Path) -> None:
    from evo.tools import file_interface

    out = tmp_path / "ins"
    _cli(["run", str(village_gps), "--init", "groundtruth", "--out", str(out)])
    tum = np.loadtxt(out / "trajectory.tum")
    traj = file_interface.read_euroc_csv_trajectory(str(out / "trajectory_euroc.csv"))
    np.testing.assert_allclose(traj.positions_xyz, tum[:, 1:4], atol=1e-6)
    np.testing.assert_allclose(traj.timestamps, tum[:, 0], atol=1e-9)
    np.testing.assert_allclose(np.abs(traj.orientations_quat_wxyz),
                               np.abs(tum[:, [7, 4, 5, 6]]), atol=1e-6)
    cov = np.loadtxt(out / "pose_covariance.csv", delimiter=",", skiprows=1)
    assert cov.shape == (len(tum), 13)
    states = (out / "states.csv").read_text().splitlines()
    assert states[0].startswith("t_ns,p_W_B_x") and len(states) == len(tum) + 1
    std_p = np.loadtxt(out / "states.csv", delimiter=",", skiprows=1)[:, 20:23]
    # pose_covariance: θ upper triangle (6), then position's; its diagonal is std_p².
    np.testing.assert_allclose(cov[:, [7, 10, 12]], std_p**2, rtol=1e-6)


def test_gps_outage_windows_and_gps_until(village_gps: Path, tmp_path: Path) -> None:
    import json

    def fused(args: list[str]) -> dict:
        out = tmp_path / str(abs(hash(tuple(args))))
        _cli(["run", str(village_gps), "--init", "groundtruth", "--out", str(out), *args])
        return json.loads((out / "report.json").read_text())

    full = fused([])
    cut = fused(["--gps-outage", "2:3", "--gps-outage", "6.5:0.4"])
    until = fused(["--gps-until", "4"])
    n = full["measurements"]["gps"]["fused"]
    assert n >= 7
    # Fixes at 1 Hz: 2, 3, 4 s in [2, 5) and none in [6.5, 6.9).
    assert cut["gps_outage_fixes_skipped"] == 3
    assert cut["measurements"]["gps"]["fused"] == n - 3
    assert until["measurements"]["gps"]["fused"] == n - until["gps_outage_fixes_skipped"]
    assert until["gps_outage_fixes_skipped"] >= 3
    # The configured outage is evaluated like a gap in the GPS stream: one outage, from the
    # last fix before it (1 s) to the first after it (5 s); the clean run has none.
    (outage,) = cut["gps_outages"]
    assert outage["duration_s"] == pytest.approx(4.0, abs=1e-6)
    assert cut["outage_max_error_m"] == [outage["error_max_m"]]
    assert not full.get("gps_outages")
    # --gps-until: from the last fix fused (4 s) to the end of the run, marked as such.
    (tail,) = until["gps_outages"]
    assert tail["to_end"] is True
    assert tail["start_s"] == pytest.approx(4.0, abs=0.05)
    assert tail["error_max_m"] >= tail["error_start_m"]
    # Fixes outside the run (before --start, after --duration) were never fed: they do not
    # close an outage (a probe: the first began 6 s before the run, unmarked).
    late = fused(["--start", "3", "--gps-outage", "0:3.5"])  # GPS off 3-6.5 s
    first = late["gps_outages"][0]
    assert first["from_start"] is True
    assert first["start_s"] == pytest.approx(0.0, abs=0.05)
    assert first["duration_s"] == pytest.approx(4.0, abs=0.05)
    short = fused(["--duration", "5", "--gps-outage", "1.5:3.6"])  # GPS off 1.5-5.1 s
    (tail,) = short["gps_outages"]
    assert tail["to_end"] is True
    assert tail["duration_s"] == pytest.approx(4.0, abs=0.05)
    with pytest.raises(AssertionError):
        _cli(["run", str(village_gps), "--gps-outage", "2-3", "--out", str(tmp_path / "x")])


def test_compare_takes_the_gps_outage_switches(village_gps: Path, tmp_path: Path) -> None:
    import json

    out = tmp_path / "cmp"
    _cli(["compare", str(village_gps), "--out", str(out), "--methods", "ins", "--no-figures",
          "--no-sonar", "--gps-outage", "2:3"])
    rep = json.loads((out / "compare.json").read_text())["ins"]
    assert rep["gps_outage_fixes_skipped"] == 3
    (outage,) = rep["gps_outages"]
    assert outage["duration_s"] == pytest.approx(4.0, abs=1e-6)
    assert rep["outage_max_error_m"] == [outage["error_max_m"]]
    assert "max err in outages" in (out / "compare.md").read_text()


def test_an_outage_after_the_end_of_the_data_is_warned(
        village_gps: Path, caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.options import InitOptions

    with caplog.at_level("WARNING", logger="svains.replay.replay"):
        run_method(load_dataset(village_gps), "ins",
                   RunConfig(init=InitOptions(mode="groundtruth"), gps_outages=((100.0, 5.0),)))
    assert "the GPS outage 100:5 starts after the end of the data" in caplog.text
