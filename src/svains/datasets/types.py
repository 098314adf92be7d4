"""In-memory types every reader and the simulator produce (the contract between packages).

All timestamps are int64 nanoseconds (``t_ns``); arrays are float64 SI unless named otherwise.
Frames follow ``docs/conventions.md``: ``T_B_S`` is sensor-to-body (EuRoC's ``T_BS``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

DEFAULT_GRAVITY_W = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class ImuCalib:
    """IMU sensor.yaml: ``T_B_S`` (4, 4), noise densities (continuous-time, per √Hz)."""

    T_B_S: F64
    rate_hz: float
    gyro_noise_density: float  # rad/s/√Hz
    gyro_random_walk: float  # rad/s²/√Hz
    accel_noise_density: float  # m/s²/√Hz
    accel_random_walk: float  # m/s³/√Hz


@dataclass(frozen=True)
class ImuStream:
    """IMU samples: ``gyro_B`` (N, 3) rad/s and ``accel_B`` (N, 3) specific force m/s²."""

    t_ns: I64
    gyro_B: F64
    accel_B: F64


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
class ImageStream:
    """Image timestamps and files; images are decoded on demand by ``load(i)`` (uint8 grey)."""

    t_ns: I64
    paths: tuple[Path, ...]
    loader: Callable[[Path], NDArray[np.uint8]] = field(repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.t_ns)

    def load(self, i: int) -> NDArray[np.uint8]:
        return self.loader(self.paths[i])


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
    """GPS antenna lever arm ``p_B_G`` (3,) m and noise standard deviations."""

    p_B_G: F64
    rate_hz: float
    position_noise_std: float  # m
    velocity_noise_std: float  # m/s


@dataclass(frozen=True)
class GpsStream:
    """Antenna position ``p_W_G`` (N, 3) m and velocity ``v_W_G`` (N, 3) m/s, local world frame."""

    t_ns: I64
    p_W_G: F64
    v_W_G: F64


@dataclass(frozen=True)
class MagCalib:
    """Magnetometer: ``T_B_S`` (4, 4), reference field ``m_W`` (3,) Gauss, noise std Gauss."""

    T_B_S: F64
    rate_hz: float
    m_W: F64
    noise_std: float


@dataclass(frozen=True)
class MagStream:
    """Measured field ``m_S`` (N, 3) Gauss in the sensor frame."""

    t_ns: I64
    m_S: F64


@dataclass(frozen=True)
class SonarCalib:
    """Sonar: ``T_B_S`` (4, 4) (ranges along the sensor's +z), noise std m, ground height m."""

    T_B_S: F64
    rate_hz: float
    noise_std: float
    ground_height: float


@dataclass(frozen=True)
class SonarStream:
    """Ranges ``range_m`` (N,) along the sensor's +z axis to flat ground."""

    t_ns: I64
    range_m: F64


@dataclass(frozen=True)
class FeatureStream:
    """Stereo feature observations, one row per (frame, track), rows sorted by ``t_ns``.

    ``track_id`` (M,) int64; ``uv_left``, ``uv_right`` (M, 2) px in the rectified pair.
    """

    t_ns: I64
    track_id: I64
    uv_left: F64
    uv_right: F64
    pixel_noise_std: float

    def frame_times(self) -> I64:
        """Distinct frame timestamps (F,) in increasing order."""
        return np.unique(self.t_ns)


@dataclass
class Dataset:
    """Everything one data set holds; any stream may be ``None``.

    ``gravity_W`` (3,) m/s² comes from ``body.yaml`` (default EuRoC z-up).
    """

    root: Path
    name: str
    gravity_W: F64 = field(default_factory=lambda: np.array(DEFAULT_GRAVITY_W))
    imu: ImuStream | None = None
    imu_calib: ImuCalib | None = None
    cam0: CameraCalib | None = None
    cam1: CameraCalib | None = None
    left: ImageStream | None = None
    right: ImageStream | None = None
    groundtruth: GroundTruth | None = None
    gps: GpsStream | None = None
    gps_calib: GpsCalib | None = None
    mag: MagStream | None = None
    mag_calib: MagCalib | None = None
    sonar: SonarStream | None = None
    sonar_calib: SonarCalib | None = None
    features: FeatureStream | None = None
    missing_images: dict[str, int] = field(default_factory=dict)
    extras: dict[str, object] = field(default_factory=dict)
