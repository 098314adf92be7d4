"""Calibration and ground-truth types: plain frozen dataclasses every layer may use.

They describe sensors, not files: the data-set readers (``svains.datasets``) produce them, the
estimator (``svains.navigation``) and the front end consume them. Frames follow
``docs/conventions.md``: ``T_B_S`` is sensor-to-body (EuRoC's ``T_BS``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class ImuCalib:
    """IMU sensor.yaml: ``T_B_S`` (4, 4), noise densities (continuous-time, per √Hz)."""

    T_B_S: F64
    rate_hz: float
    gyro_noise_density: float  # rad/s/√Hz
    gyro_random_walk: float  # rad/s²/√Hz
    accel_noise_density: float  # m/s²/√Hz
    accel_random_walk: float  # m/s³/√Hz
    gyro_range: float | None = None  # rad/s, full scale (saturation); None: unknown
    accel_range: float | None = None  # m/s², full scale (saturation); None: unknown


@dataclass(frozen=True)
class CameraCalib:
    """Kalibr/EuRoC camera sensor.yaml.

    ``intrinsics`` = (fu, fv, cu, cv) px; ``distortion_model`` names the lens model
    (``radtan``/``radial-tangential``: ``distortion`` = (k1, k2, p1, p2) or (k1, k2, p1, p2, k3),
    OpenCV order; ``equidistant``: (k1, k2, k3, k4), Kannala-Brandt; see
    ``svains.geometry.distortion``); ``T_B_C`` (4, 4) camera-to-body; ``resolution`` = (width,
    height) px; ``timeshift_cam_imu_s`` the camera-IMU offset (s, t_imu = t_cam + timeshift) that
    the reader has already added to the image stamps (recorded here, never applied again).
    """

    name: str
    T_B_C: F64
    rate_hz: float
    resolution: tuple[int, int]
    intrinsics: F64
    distortion_model: str
    distortion: F64
    timeshift_cam_imu_s: float = 0.0

    @property
    def K(self) -> F64:
        fu, fv, cu, cv = self.intrinsics
        return np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class GroundTruth:
    """EuRoC ground truth of the body (IMU) frame: position, attitude, velocity, biases.

    ``p_W_B`` (N, 3) m, ``q_W_B_wxyz`` (N, 4), ``v_W_B`` (N, 3) m/s, ``bg_B`` (N, 3) rad/s,
    ``ba_B`` (N, 3) m/s².
    """

    t_ns: I64
    p_W_B: F64
    q_W_B_wxyz: F64
    v_W_B: F64
    bg_B: F64
    ba_B: F64


@dataclass(frozen=True)
class GpsCalib:
    """GPS antenna lever arm ``p_B_G`` (3,) m and noise standard deviations;
    ``timeshift_gps_imu_s`` (s): ``t_imu = t_gps + timeshift`` (a receiver that stamps its
    fixes 0.1 s after they hold: -0.1), applied once when the stamps are read;
    ``position_correlation_s`` (s): the time over which the positions' noise stays correlated
    (a receiver's multipath and atmosphere; 0: white from fix to fix)."""

    p_B_G: F64
    rate_hz: float
    position_noise_std: float  # m
    velocity_noise_std: float  # m/s
    timeshift_gps_imu_s: float = 0.0
    position_correlation_s: float = 0.0


@dataclass(frozen=True)
class MagCalib:
    """Magnetometer: ``T_B_S`` (4, 4), reference field ``m_W`` (3,) Gauss, noise std Gauss."""

    T_B_S: F64
    rate_hz: float
    m_W: F64
    noise_std: float


@dataclass(frozen=True)
class SonarCalib:
    """Sonar: ``T_B_S`` (4, 4) (ranges along the sensor's +z), noise std m, ground height m."""

    T_B_S: F64
    rate_hz: float
    noise_std: float
    ground_height: float


@dataclass(frozen=True)
class Rig:
    """Everything the estimator knows about the sensors, besides their measurements.

    ``gravity_W`` (3,) m/s²; ``imu_period_s``: the IMU's nominal sample period, used only
    without an IMU calibration (then it sets a sample's white noise and seeds the guard's
    spacing; ``imu.rate_hz`` does both when there is one); a replay takes the median step of
    the recording;
    calibrations ``None`` when the sensor is absent (no IMU calibration: EuRoC ADIS16448 noise,
    identity mount). ``cam0``/``cam1`` define the rectified stereo pair the vision methods use.
    """

    gravity_W: tuple[float, float, float] = (0.0, 0.0, -9.81)
    imu_period_s: float = 0.005
    imu: ImuCalib | None = None
    cam0: CameraCalib | None = None
    cam1: CameraCalib | None = None
    gps: GpsCalib | None = None
    mag: MagCalib | None = None
    sonar: SonarCalib | None = None
