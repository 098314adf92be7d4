"""Simulator sensor models: IMU noise statistics, bias walk, GPS outages, magnetometer, sonar,
ray occlusion and the configuration API."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svains.errors import ConfigError
from svains.sim.config import ImuConfig, SimConfig
from svains.sim.sensors import (
    gps_keep_mask,
    occluded,
    sample_times_ns,
    simulate_gps,
    simulate_imu,
    simulate_mag,
    simulate_sonar,
)
from svains.sim.trajectory import village_trajectory

G_W = np.array([0.0, 0.0, -9.81])


@pytest.fixture(scope="module")
def truth():
    traj = village_trajectory(60.0, (60.0, 45.0), 5.0, 2.0, 2.0)
    return traj.evaluate(sample_times_ns(100.0, 60.0) * 1e-9)


def test_imu_residuals_have_the_configured_std(truth) -> None:
    cfg = ImuConfig()
    imu = simulate_imu(truth, G_W, cfg, np.random.default_rng(3))
    gyro_res = imu.gyro_B - truth.omega_B
    accel_res = imu.accel_B - truth.specific_force_B(G_W)
    # paper Table 1: 50 (deg/s)² and 0.5 (m/s²)² per sample
    assert cfg.gyro_noise_std == pytest.approx(math.radians(math.sqrt(50.0)))
    assert cfg.accel_noise_std == pytest.approx(math.sqrt(0.5))
    for res, std in ((gyro_res, cfg.gyro_noise_std), (accel_res, cfg.accel_noise_std)):
        measured = res.std(axis=0)
        assert np.all(np.abs(measured / std - 1.0) < 0.10), measured / std
        assert np.all(np.abs(res.mean(axis=0)) < 0.05 * std)
    np.testing.assert_array_equal(imu.bg_B, 0.0)


def test_noise_free_imu_is_the_truth(truth) -> None:
    cfg = ImuConfig(gyro_noise_std=0.0, accel_noise_std=0.0)
    imu = simulate_imu(truth, G_W, cfg, np.random.default_rng(0))
    np.testing.assert_array_equal(imu.gyro_B, truth.omega_B)
    # level hover reads +9.81 on the up axis (EuRoC sign convention)
    assert np.median(imu.accel_B[:, 2]) == pytest.approx(9.81, abs=0.05)


def test_adis_preset_bias_random_walk(truth) -> None:
    cfg = ImuConfig.preset("adis16448")
    assert cfg.gyro_random_walk == pytest.approx(1.9393e-5)
    cfg.accel_random_walk = 0.05  # larger so the check is statistically sharp
    imu = simulate_imu(truth, G_W, cfg, np.random.default_rng(5))
    steps = np.diff(imu.ba_B, axis=0)
    expected = cfg.accel_random_walk * math.sqrt(1.0 / cfg.rate_hz)
    assert steps.std() == pytest.approx(expected, rel=0.1)
    with pytest.raises(ConfigError, match="unknown IMU preset"):
        ImuConfig.preset("tactical")


def test_gps_outages_and_lever_arm(truth) -> None:
    t = sample_times_ns(1.0, 110.0)
    keep = gps_keep_mask(t, SimConfig().gps.outages)
    kept_s = t[keep] * 1e-9
    for start in (15, 40, 65, 90):
        assert not np.any((kept_s >= start) & (kept_s < start + 10))
        assert np.any(np.isclose(kept_s, start + 10))  # regained after 10 s
    assert keep.sum() == 111 - 40
    cfg = SimConfig().gps
    cfg.position_noise_std = cfg.velocity_noise_std = 0.0
    p, v = simulate_gps(truth, cfg, np.random.default_rng(0))
    np.testing.assert_allclose(p - truth.p_W_B, truth.R_W_B @ np.array(cfg.p_B_G))
    assert np.linalg.norm(v - truth.v_W_B, axis=1).max() < 0.15 * np.abs(truth.omega_B).max()


def test_magnetometer_and_sonar(truth) -> None:
    cfg = SimConfig()
    m = simulate_mag(truth, cfg.mag.m_W, 0.0, np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), np.linalg.norm(cfg.mag.m_W))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", truth.R_W_B, m),
                               np.tile(cfg.mag.m_W, (len(m), 1)), atol=1e-12)
    cfg.sonar.noise_std = 0.0
    r = simulate_sonar(truth, cfg.sonar, 0.0, np.random.default_rng(0))
    # the sensor sits 5 cm below the body origin; the body flies at 2 m, tilted a few degrees
    tilt_cos = truth.R_W_B[:, 2, 2]
    p_S_z = truth.p_W_B[:, 2] + truth.R_W_B[:, 2, :] @ np.array(cfg.sonar.p_B_S)
    np.testing.assert_allclose(r, p_S_z / tilt_cos, rtol=1e-12)
    assert np.all((r > 1.9) & (r < 2.05))


def test_ray_occlusion_by_a_unit_cube() -> None:
    normals = np.array([[[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]],
                       dtype=float)
    offsets = np.ones((1, 6))  # |x|, |y|, |z| <= 1
    origin = np.array([-5.0, 0.0, 0.0])
    points = np.array([
        [5.0, 0.0, 0.0],    # behind the cube
        [-1.0, 0.5, 0.5],   # on the near face: visible
        [1.0, 0.5, 0.5],    # on the far face: hidden
        [5.0, 3.0, 0.0],    # ray passes beside the cube
        [-3.0, 0.0, 0.0],   # in front of the cube
    ])  # fmt: skip
    np.testing.assert_array_equal(occluded(origin, points, normals, offsets),
                                  [True, False, True, False, False])


def test_config_yaml_round_trip_and_errors(tmp_path) -> None:
    cfg = SimConfig(duration_s=12.5, seed=7)
    cfg.camera.rate_hz = 5.0
    cfg.gps.outages = [[3.0, 2.0]]
    path = tmp_path / "sim.yaml"
    cfg.to_yaml(path)
    back = SimConfig.from_yaml(path)
    assert back == cfg
    path.write_text("imu:\n  gyro_noise: 1.0\n")
    with pytest.raises(ConfigError, match=r"unknown simulator config key 'imu\.gyro_noise'"):
        SimConfig.from_yaml(path)
    with pytest.raises(ConfigError, match=r"camera.rate_hz must be in \(0, 20\]"):
        SimConfig(camera=SimConfig().camera.__class__(rate_hz=25.0)).validate()
    # no receiver gives 250 Hz: the readers would take the fixes for stamps in µs (a review)
    with pytest.raises(ConfigError, match=r"gps.rate_hz must be in \(0, 200\]"):
        SimConfig(gps=SimConfig().gps.__class__(rate_hz=250.0)).validate()
    SimConfig(gps=SimConfig().gps.__class__(rate_hz=200.0)).validate()
    with pytest.raises(ConfigError, match=r"needs trajectory\.tum_path"):
        SimConfig(scenario="trajectory").validate()
    with pytest.raises(ConfigError, match="scenario must be"):
        SimConfig(scenario="city").validate()


def test_gps_position_noise_correlated_over_its_time_constant(truth) -> None:
    """``gps.position_correlation_s`` τ: a first-order Gauss-Markov noise of the same σ, whose
    lag-one correlation at 100 Hz is exp(-0.01/τ); 0 keeps the white draws."""
    t = sample_times_ns(100.0, 60.0)
    cfg = SimConfig().gps
    white, _ = simulate_gps(truth, cfg, np.random.default_rng(3), t)
    e = np.random.default_rng(3).standard_normal((len(t), 3))
    np.testing.assert_allclose(white - (truth.p_W_B + truth.R_W_B @ np.array(cfg.p_B_G)),
                               cfg.position_noise_std * e, rtol=0, atol=1e-12)  # fmt: skip
    cfg.position_correlation_s = 2.0
    runs = [simulate_gps(truth, cfg, np.random.default_rng(s), t)[0]
            - (truth.p_W_B + truth.R_W_B @ np.array(cfg.p_B_G)) for s in range(20)]
    noise = np.concatenate(runs, axis=1)  # (N, 60): 20 runs of 3 axes
    assert np.std(noise) == pytest.approx(cfg.position_noise_std, rel=0.1)
    lag1 = np.mean(noise[1:] * noise[:-1]) / np.mean(noise**2)
    assert lag1 == pytest.approx(math.exp(-0.01 / 2.0), abs=2e-3)
    lag200 = np.mean(noise[200:] * noise[:-200]) / np.mean(noise**2)  # 2 s: e^-1
    assert lag200 == pytest.approx(math.exp(-1.0), abs=0.1)
    with pytest.raises(ValueError, match="needs the fixes' times"):
        simulate_gps(truth, cfg, np.random.default_rng(0))
