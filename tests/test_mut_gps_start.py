"""The in-flight GPS start places the body at the first IMU sample exactly (issue 26: moving the
first fix to that sample by twice its time offset survived the suite, whose flight test allows
GPS-noise-sized errors).

Closed form: level flight at a constant 10 m/s, noise-free GPS fixes stamped 2.5 ms before an
IMU sample. The start (the first IMU sample at or after the first fix) must be the fix moved
along the velocity by exactly that offset.
"""

from __future__ import annotations

import numpy as np

from svains.models.state import BIASED, P, V
from svains.navigation.init import GpsArrays, ImuArrays, InitData, initialise
from svains.navigation.options import InitOptions
from svains.sensors.types import GpsCalib

G_W = (0.0, 0.0, -9.81)
V_W = np.array([8.0, -6.0, 0.0])  # 10 m/s, level
P0_W = np.array([100.0, 50.0, 20.0])  # body position at t = 0


def _flight() -> InitData:
    t_imu = np.arange(0, 3_000_000_000, 5_000_000, dtype=np.int64)  # 200 Hz
    n = t_imu.size
    imu = ImuArrays(t_imu, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)))
    t_gps = np.array([1_002_500_000, 2_002_500_000], np.int64)  # 2.5 ms before an IMU sample
    p_gps = P0_W + np.outer(t_gps * 1e-9, V_W)
    gps = GpsArrays(t_gps, p_gps, np.tile(V_W, (2, 1)))
    cal = GpsCalib(p_B_G=np.zeros(3), rate_hz=1.0, position_noise_std=0.02,
                   velocity_noise_std=0.01)  # fmt: skip
    return InitData("level flight", G_W, imu, gps=gps, gps_calib=cal)


def test_gps_start_moves_the_first_fix_to_the_first_imu_sample_exactly() -> None:
    init = initialise(_flight(), BIASED, InitOptions(mode="gps"))
    assert init.t_ns == 1_005_000_000
    np.testing.assert_allclose(init.x[V], V_W, rtol=0, atol=1e-12)
    # The body's true position at t0, to rounding (an offset applied twice would put it
    # v * 2.5 ms = 2.5 cm off).
    np.testing.assert_allclose(init.x[P], P0_W + V_W * init.t_ns * 1e-9, rtol=0, atol=1e-9)
