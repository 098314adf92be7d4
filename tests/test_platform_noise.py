"""The platform noise rule (``navigation.platform_noise``): the white noise measured at rest
replaces the calibration only where it exceeds it beyond the estimate's own spread."""

from __future__ import annotations

import numpy as np
import pytest

from svains.navigation.options import NoiseOptions
from svains.navigation.platform_noise import measure_static_noise, platform_noise
from svains.sensors.types import ImuCalib

RATE_HZ = 200.0
GYRO_D, ACCEL_D = 1.7e-4, 2.0e-3  # rad/s/sqrt(Hz), m/s²/sqrt(Hz) (EuRoC's Kalibr figures)


def _calib() -> ImuCalib:
    return ImuCalib(T_B_S=np.eye(4), rate_hz=RATE_HZ, gyro_noise_density=GYRO_D,
                    gyro_random_walk=2e-5, accel_noise_density=ACCEL_D,
                    accel_random_walk=3e-3)  # fmt: skip


def _rest(rng: np.random.Generator, gyro_d: float, accel_d: float, seconds: float = 2.0):
    n = int(seconds * RATE_HZ)
    s = np.sqrt(RATE_HZ)  # per-sample std of white noise of density d: d sqrt(rate)
    gyro = 0.01 + gyro_d * s * rng.standard_normal((n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + accel_d * s * rng.standard_normal((n, 3))
    return gyro, accel


def test_block_means_recover_the_density_of_white_noise() -> None:
    rng = np.random.default_rng(0)
    gyro, accel = _rest(rng, 5 * GYRO_D, 3 * ACCEL_D, seconds=20.0)
    m = measure_static_noise(gyro, accel, 1.0 / RATE_HZ, 0.1)
    assert m.gyro_density == pytest.approx(5 * GYRO_D, rel=0.1)
    assert m.accel_density == pytest.approx(3 * ACCEL_D, rel=0.1)
    assert m.dof == 3 * (200 - 1)


def test_an_imu_with_its_calibrated_noise_keeps_the_calibration() -> None:
    # The simulator's case: the rule must leave a consistent filter alone (0.999 quantile:
    # at most a rare start is changed, and then by a few tens of percent).
    applied = 0
    for seed in range(200):
        gyro, accel = _rest(np.random.default_rng(seed), GYRO_D, ACCEL_D)
        m = measure_static_noise(gyro, accel, 1.0 / RATE_HZ, 0.1)
        opts, info = platform_noise(NoiseOptions(), _calib(), m)
        assert info is not None
        applied += info["gyro"]["applied"] + info["accel"]["applied"]
        if not (info["gyro"]["applied"] or info["accel"]["applied"]):
            assert opts == NoiseOptions()
    assert applied <= 2


def test_a_vibrating_platform_takes_the_measured_density_and_a_wider_random_walk() -> None:
    gyro, accel = _rest(np.random.default_rng(1), 5 * GYRO_D, 8 * ACCEL_D)
    m = measure_static_noise(gyro, accel, 1.0 / RATE_HZ, 0.1)
    opts, info = platform_noise(NoiseOptions(), _calib(), m)
    assert info is not None and info["gyro"]["applied"] and info["accel"]["applied"]
    assert opts.gyro_noise_density == pytest.approx(m.gyro_density)
    assert opts.accel_noise_density == pytest.approx(m.accel_density)
    r_g = m.gyro_density / GYRO_D
    assert opts.gyro_random_walk == pytest.approx(2e-5 * np.sqrt(r_g))
    assert 3.5 < r_g < 6.5
    # Given explicitly, a density is the user's: kept, and the rule can be turned off.
    mine = NoiseOptions(gyro_noise_density=1e-3)
    opts, info = platform_noise(mine, _calib(), m)
    assert opts.gyro_noise_density == 1e-3 and not info["gyro"]["applied"]
    # a random walk set beside it is kept too; set alone it scales with the measured density
    # as the calibration's does (docs/own-sensor.md)
    opts, _ = platform_noise(NoiseOptions(gyro_noise_density=1e-3, gyro_random_walk=3e-5),
                             _calib(), m)  # fmt: skip
    assert opts.gyro_random_walk == 3e-5
    opts, _ = platform_noise(NoiseOptions(gyro_random_walk=3e-5), _calib(), m)
    assert opts.gyro_random_walk == pytest.approx(3e-5 * np.sqrt(r_g))
    assert platform_noise(NoiseOptions(static_rule=False), _calib(), m) == (
        NoiseOptions(static_rule=False), None)


@pytest.mark.parametrize(("factor", "said"), [(1e-3, "The measured one is used"),
                                              (1e3, "The calibration is kept")])
def test_a_density_in_another_unit_is_warned(factor: float, said: str,
                                             caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    """A calibration 1000x off (per sample, deg, mg) passed in silence (a user's probe); the
    vibrating platform of EuRoC (5-8x) is no unit and stays unsaid."""
    gyro, accel = _rest(np.random.default_rng(2), 5 * GYRO_D, 8 * ACCEL_D)
    m = measure_static_noise(gyro, accel, 1.0 / RATE_HZ, 0.1)
    with caplog.at_level("WARNING", logger="svains.navigation.platform_noise"):
        platform_noise(NoiseOptions(), _calib(), m)
        assert caplog.text == ""
        cal = _calib()
        wrong = ImuCalib(T_B_S=cal.T_B_S, rate_hz=RATE_HZ, gyro_noise_density=GYRO_D,
                         gyro_random_walk=2e-5, accel_noise_density=ACCEL_D * factor,
                         accel_random_walk=3e-3)  # fmt: skip
        platform_noise(NoiseOptions(), wrong, m)
    assert "the accelerometer's white noise measured at rest is" in caplog.text
    assert "in another unit" in caplog.text and said in caplog.text
    assert "the gyro's" not in caplog.text


def test_a_rest_many_times_noisier_than_the_calibration_is_warned(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A tactical IMU on a start that swayed read 18-31x its calibration, taken in silence,
    its accuracy halved (a user's probe): above 10x it is said, with the way to keep the
    calibration. EuRoC's rotors (5-8x) stay unsaid (the test above)."""
    gyro, accel = _rest(np.random.default_rng(3), 20 * GYRO_D, 4 * ACCEL_D)
    m = measure_static_noise(gyro, accel, 1.0 / RATE_HZ, 0.1)
    with caplog.at_level("WARNING", logger="svains.navigation.platform_noise"):
        opts, info = platform_noise(NoiseOptions(), _calib(), m)
    assert info is not None and info["gyro"]["applied"] and 15 < info["gyro"]["ratio"] < 25
    assert opts.gyro_noise_density == pytest.approx(m.gyro_density)
    assert caplog.text.count("white noise measured at rest is") == 1
    assert "the gyro's white noise measured at rest is" in caplog.text
    assert "a start that was not quite at rest" in caplog.text
    assert "--set noise.static_rule=false keeps the calibration" in caplog.text


@pytest.mark.realdata
def test_the_euroc_static_start_measures_its_rotor_vibration(euroc_micro) -> None:
    from svains.datasets.loader import load_dataset

    ds = load_dataset(euroc_micro)
    assert ds.imu is not None and ds.imu_calib is not None
    R_B_S = ds.imu_calib.T_B_S[:3, :3]
    n = int(2.0 * ds.imu_calib.rate_hz)
    m = measure_static_noise(ds.imu.gyro_B[:n] @ R_B_S.T, ds.imu.accel_B[:n] @ R_B_S.T,
                             1.0 / ds.imu_calib.rate_hz, 0.1)  # fmt: skip
    _, info = platform_noise(NoiseOptions(), ds.imu_calib, m)
    # Rotors running: 5.5x the gyro and 7.9x the accelerometer calibration (0.1 s blocks).
    assert info is not None and info["gyro"]["applied"] and info["accel"]["applied"]
    assert 4.0 < info["gyro"]["ratio"] < 7.0
    assert 6.0 < info["accel"]["ratio"] < 10.0


def test_rest_noise_measures_a_rest_and_refuses_a_turn() -> None:
    from svains.navigation.options import InitOptions
    from svains.navigation.platform_noise import rest_noise

    gyro, accel = _rest(np.random.default_rng(2), 5 * GYRO_D, 8 * ACCEL_D, seconds=4.0)
    t_ns = (np.arange(len(gyro)) * 1e9 / RATE_HZ).astype(np.int64)
    m = rest_noise(t_ns, gyro, accel, InitOptions())
    first = int(2.0 * RATE_HZ) + 1  # the first static_s seconds, both ends
    assert m == measure_static_noise(gyro[:first], accel[:first], 1.0 / RATE_HZ, 0.1)
    turning = gyro.copy()
    turning[200:, 2] += 0.2  # a turn 1 s in: no rest
    assert rest_noise(t_ns, turning, accel, InitOptions()) is None
    assert rest_noise(t_ns[:5], gyro[:5], accel[:5], InitOptions()) is None


@pytest.mark.realdata
def test_an_in_flight_euroc_start_takes_the_recordings_rest(euroc_micro, tmp_path) -> None:
    """A start from the true state 50 s into the flight kept the Kalibr noise: every frame,
    NEES 117 (a user's probe); with the recording's first 2 s at rest, 16."""
    import json

    from typer.testing import CliRunner

    from svains.cli.main import app

    res = CliRunner().invoke(app, ["run", str(euroc_micro), "--out", str(tmp_path / "r"),
                                   "--init", "groundtruth", "--start", "50", "--duration", "1",
                                   "--no-gps", "--no-mag"])  # fmt: skip
    assert res.exit_code == 0, res.output
    noise = json.loads((tmp_path / "r" / "report.json").read_text())["init"]["imu_noise"]
    assert noise["measured_at"] == "rest_noise"
    assert noise["gyro"]["applied"] and 4.0 < noise["gyro"]["ratio"] < 7.0
    assert noise["accel"]["applied"] and 6.0 < noise["accel"]["ratio"] < 10.0
