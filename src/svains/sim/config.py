"""Simulator configuration: nested dataclasses with defaults from the paper (section 6.1, Table 1).

Noise parameterisation (read this before changing a value): every ``*_noise_std`` here is a
**discrete, per-sample** standard deviation at the sensor's own rate, which is how the paper's
Table 1 states its variances. The IMU's ``sensor.yaml`` needs EuRoC's continuous-time densities;
the simulator converts them there with ``density = std_per_sample / sqrt(rate_hz)``. Bias random
walks are continuous-time densities (EuRoC style, per √Hz) because they only make sense that way.

Gyro value chosen (Table 1 is garbled): the extraction prints "Gyro 50 (deg/s)2". The other rows
keep their digits and lose only "×", "−" and superscripts ("1104" is 1×10⁻⁴ G²), and "50" has no
room for a lost exponent, so it is read literally: variance 50 (deg/s)² per sample at 100 Hz,
σ = √50 deg/s ≈ 0.1234 rad/s. The table is titled "Sensors and vibration noise levels": like the
accelerometer's 0.5 (m/s²)² (σ ≈ 0.71 m/s², far above a bare MEMS sensor) it includes airframe
vibration, which explains its size.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from svains.datasets.validate import GRAVITY_RANGE_M_S2
from svains.errors import ConfigError
from svains.sensors.units import MAX_GPS_HZ
from svains.yaml_io import load_yaml

PAPER_GYRO_STD = math.radians(math.sqrt(50.0))  # rad/s per sample (see module docstring)
PAPER_ACCEL_STD = math.sqrt(0.5)  # m/s² per sample

# Upper bounds that keep a simulation in memory (an hour of 100 Hz IMU with its ground truth
# and kinematics is ~100 MB of arrays; a typo such as 1e9 s must not ask for 150 GB).
MAX_DURATION_S = 3600.0
MAX_RATE_HZ = 1000.0
MAX_CAMERA_RATE_HZ = 20.0  # stereo frames per second the simulator renders or projects
MAX_TIMESHIFT_S = 1.0  # |camera.timeshift_cam_imu| (s): real offsets are tens of ms

# EuRoC ADIS16448 figures (continuous densities, from the EuRoC imu0/sensor.yaml).
ADIS_GYRO_DENSITY = 1.6968e-4  # rad/s/√Hz
ADIS_GYRO_RW = 1.9393e-5  # rad/s²/√Hz
ADIS_ACCEL_DENSITY = 2.0e-3  # m/s²/√Hz
ADIS_ACCEL_RW = 3.0e-3  # m/s³/√Hz


@dataclass
class ImuConfig:
    """IMU at the body origin (body frame = IMU frame). Noise std per sample; random walks as
    continuous densities; initial biases (rad/s, m/s²) in the body frame."""

    rate_hz: float = 100.0
    gyro_noise_std: float = PAPER_GYRO_STD
    accel_noise_std: float = PAPER_ACCEL_STD
    gyro_random_walk: float = 0.0
    accel_random_walk: float = 0.0
    gyro_bias_init: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    accel_bias_init: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    @classmethod
    def preset(cls, name: str) -> ImuConfig:
        """``"paper"`` (Table 1, no bias drift) or ``"adis16448"`` (EuRoC figures, with drift)."""
        if name == "paper":
            return cls()
        if name == "adis16448":
            rate = 100.0
            return cls(
                rate_hz=rate,
                gyro_noise_std=ADIS_GYRO_DENSITY * math.sqrt(rate),
                accel_noise_std=ADIS_ACCEL_DENSITY * math.sqrt(rate),
                gyro_random_walk=ADIS_GYRO_RW,
                accel_random_walk=ADIS_ACCEL_RW,
            )
        raise ConfigError(f"unknown IMU preset {name!r} (use 'paper' or 'adis16448')")


@dataclass
class GpsConfig:
    """GPS antenna at lever arm ``p_B_G`` (m); outages ``[start_s, duration_s]`` pairs; its
    position noise white, or correlated over ``position_correlation_s`` (s)."""

    enabled: bool = True
    rate_hz: float = 1.0
    position_noise_std: float = math.sqrt(2.0)  # Table 1: variance 2 m²
    velocity_noise_std: float = 0.1
    # s: the positions' noise a first-order Gauss-Markov process with this time constant and
    # ``position_noise_std`` (a real receiver's: seconds to a minute); 0: white. Written to
    # the calibration as ``position_correlation_s``.
    position_correlation_s: float = 0.0
    p_B_G: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.15])
    outages: list[list[float]] = field(
        default_factory=lambda: [[15.0, 10.0], [40.0, 10.0], [65.0, 10.0], [90.0, 10.0]]
    )


@dataclass
class MagConfig:
    """Magnetometer aligned with the body. ``m_W`` in Gauss, world x east, y north, z up: the
    field near Milan (the authors' lab), about 0.47 G total, inclination 60°, declination 3° E."""

    enabled: bool = True
    rate_hz: float = 100.0
    noise_std: float = 0.01  # Table 1: variance 1e-4 G²
    m_W: list[float] = field(default_factory=lambda: [0.0123, 0.2347, -0.4070])


@dataclass
class SonarConfig:
    """Downward sonar altimeter at ``p_B_S`` (m), ranging along -z_B, over flat ground."""

    enabled: bool = True
    rate_hz: float = 20.0
    noise_std: float = 0.02
    p_B_S: list[float] = field(default_factory=lambda: [0.0, 0.0, -0.05])


@dataclass
class CameraConfig:
    """Ideal rectified stereo pair (no distortion), EuRoC-like intrinsics.

    Village: left camera at ``p_B_C`` (m), looking along body +x tilted down by
    ``tilt_down_deg``; the right camera ``baseline`` m along the left camera's x axis (to the
    body's right). Scenario ``trajectory`` (EuRoC flights, whose IMU has x up) uses EuRoC's
    nominal cam0 mount instead (optical axis along body +z), see ``svains.sim.simulate``.
    ``image_noise_std`` is in grey levels; ``pixel_noise_std`` (px) perturbs features0.
    ``lens``: ``pinhole`` (ideal rectified pair) or ``equidistant``: both cameras then get a
    Kannala-Brandt fisheye lens with the same ``f, cu, cv`` and ``fisheye_distortion``
    (k1..k4), rendered by ``svains.sim.fisheye``; rectification maps such a pair back to the
    ideal pinhole pair, in which features0 stays.
    """

    enabled: bool = True
    rate_hz: float = 2.0
    width: int = 752
    height: int = 480
    f: float = 458.654
    cu: float = 367.215
    cv: float = 248.375
    baseline: float = 0.11
    tilt_down_deg: float = 20.0
    p_B_C: list[float] = field(default_factory=lambda: [0.15, 0.055, -0.05])
    pixel_noise_std: float = 0.5  # features0 pixel noise (px)
    image_noise_std: float = 2.0  # grey-level noise added to rendered images
    brightness_amplitude: float = 0.0  # relative exposure change (0.1 = ±10 %)
    brightness_period_s: float = 20.0
    max_depth: float = 40.0  # landmarks farther than this are not reported in features0
    render_images: bool = True
    lens: str = "pinhole"
    # True camera-IMU time offset (s, Kalibr's t_imu = t_cam + shift): images and features0
    # are stamped t_capture - shift; sensor.yaml keeps 0 (the offset a filter must estimate).
    timeshift_cam_imu: float = 0.0
    # A real wide-angle Kannala-Brandt lens (RealSense T265 class) on EuRoC-like intrinsics:
    # about 94° horizontal and 112° diagonal field of view at 752x480.
    fisheye_distortion: list[float] = field(
        default_factory=lambda: [-0.00626, 0.04132, -0.03836, 0.00649]
    )


@dataclass
class WorldConfig:
    """Village layout: rectangle ``size`` (m) flown at ``altitude`` (m), houses around it."""

    size: list[float] = field(default_factory=lambda: [60.0, 45.0])
    corner_radius: float = 5.0
    n_outer_houses: int = 22
    n_inner_objects: int = 14
    n_poles: int = 10
    clearance: float = 3.5  # min distance from the path to any object (m)
    moving_object: bool = False
    moving_amplitude: float = 3.0  # m
    moving_period_s: float = 12.0


@dataclass
class TrajectoryConfig:
    """``village``: rectangle at ``altitude`` m and ``speed`` m/s, halting at rest for each of
    ``stops`` (``[start_s, duration_s]`` pairs; the speed eases down to zero over the
    ``stop_ramp_s`` before ``start_s`` and back up over those after the stop, at rest to within
    one knot, ``knot_dt_s``, of its ends: a stop at 0 s is a static start). ``trajectory``: TUM
    file."""

    altitude: float = 2.0
    speed: float = 2.0
    bank: bool = True
    vibration_deg: float = 0.3
    vibration_hz: float = 3.0
    tum_path: str | None = None
    knot_dt_s: float = 0.05
    stops: list[list[float]] = field(default_factory=list)
    stop_ramp_s: float = 2.0


@dataclass
class SimConfig:
    """Everything the simulator needs; ``to_yaml``/``from_yaml`` round-trip it."""

    scenario: str = "village"
    duration_s: float = 110.0
    seed: int = 0
    gravity_W: list[float] = field(default_factory=lambda: [0.0, 0.0, -9.81])
    imu: ImuConfig = field(default_factory=ImuConfig)
    gps: GpsConfig = field(default_factory=GpsConfig)
    mag: MagConfig = field(default_factory=MagConfig)
    sonar: SonarConfig = field(default_factory=SonarConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid value."""
        _check_types(self, "")
        if self.scenario not in ("village", "trajectory"):
            raise ConfigError(f"scenario must be 'village' or 'trajectory', got {self.scenario!r}")
        if self.scenario == "trajectory" and not self.trajectory.tum_path:
            raise ConfigError("scenario 'trajectory' needs trajectory.tum_path (a TUM file)")
        tc = self.trajectory
        if not tc.stop_ramp_s > 0:
            raise ConfigError(f"trajectory.stop_ramp_s must be > 0, got {tc.stop_ramp_s}")
        for stop in tc.stops:
            if not isinstance(stop, list) or len(stop) != 2 or not stop[1] >= 0:
                raise ConfigError("trajectory.stops must be [start_s, duration_s] pairs with "
                                  f"duration_s >= 0, got {stop}")  # fmt: skip
            if not stop[0] < self.duration_s:
                raise ConfigError(f"trajectory.stops: the stop {stop} starts after the flight's "
                                  f"end ({self.duration_s:g} s)")  # fmt: skip
        ordered = sorted(tc.stops)
        for a, b in itertools.pairwise(ordered):
            # overlapping ramps multiply (``speed_profile``): a crawl between the stops
            if b[0] - (a[0] + a[1]) < 2.0 * tc.stop_ramp_s:
                raise ConfigError(f"trajectory.stops: the stops {a} and {b} are less than two "
                                  f"ramps apart (2 x stop_ramp_s = {2 * tc.stop_ramp_s:g} s): "
                                  "merge them or move them apart")  # fmt: skip
        if tc.stops and not tc.speed > 0:
            raise ConfigError(f"trajectory.stops need a cruise speed > 0, got {tc.speed}")
        if tc.stops and self.scenario != "village":
            raise ConfigError("trajectory.stops apply to the village scenario (a TUM file holds "
                              "its own stops)")  # fmt: skip
        if not 0 < self.duration_s <= MAX_DURATION_S:
            raise ConfigError(
                f"duration_s must be in (0, {MAX_DURATION_S:g}], got {self.duration_s}"
            )
        if not 0 < self.camera.rate_hz <= MAX_CAMERA_RATE_HZ:
            raise ConfigError(f"camera.rate_hz must be in (0, {MAX_CAMERA_RATE_HZ:g}], got "
                              f"{self.camera.rate_hz}")  # fmt: skip
        for name in ("imu", "gps", "mag", "sonar"):
            # a GPS no faster than a receiver gives: the readers take faster fixes for stamps
            # in another unit (a review: a 250 Hz simulated GPS was written, then refused)
            most = MAX_GPS_HZ if name == "gps" else MAX_RATE_HZ
            if not 0 < getattr(self, name).rate_hz <= most:
                raise ConfigError(f"{name}.rate_hz must be in (0, {most:g}]")
        g = math.sqrt(sum(float(v) ** 2 for v in self.gravity_W)) if len(self.gravity_W) == 3 else 0
        lo, hi = GRAVITY_RANGE_M_S2
        if not lo <= g <= hi:
            raise ConfigError(f"gravity_W must be 3 numbers of magnitude {lo}-{hi} m/s², got "
                              f"{self.gravity_W}")
        # Written into sensor.yaml files, which readers require > 0 (a filter cannot weigh a
        # noiseless measurement); image grey noise and bias random walks may be 0.
        for key in ("imu.gyro_noise_std", "imu.accel_noise_std", "gps.position_noise_std",
                    "gps.velocity_noise_std", "mag.noise_std", "sonar.noise_std",
                    "camera.pixel_noise_std"):  # fmt: skip
            part, name = key.split(".")
            if not getattr(getattr(self, part), name) > 0:
                raise ConfigError(f"{key} must be > 0, got {getattr(getattr(self, part), name)}")
        for key in ("imu.gyro_random_walk", "imu.accel_random_walk", "camera.image_noise_std",
                    "gps.position_correlation_s"):  # fmt: skip
            part, name = key.split(".")
            if not getattr(getattr(self, part), name) >= 0:
                raise ConfigError(f"{key} must be >= 0, got {getattr(getattr(self, part), name)}")
        if self.camera.lens not in ("pinhole", "equidistant"):
            raise ConfigError(
                f"camera.lens must be 'pinhole' or 'equidistant', got {self.camera.lens!r}"
            )
        if not abs(self.camera.timeshift_cam_imu) <= MAX_TIMESHIFT_S:
            raise ConfigError(f"camera.timeshift_cam_imu must be within ±{MAX_TIMESHIFT_S:g} s, "
                              f"got {self.camera.timeshift_cam_imu}")  # fmt: skip
        if len(self.camera.fisheye_distortion) != 4:
            raise ConfigError("camera.fisheye_distortion must have 4 numbers (k1, k2, k3, k4)")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_yaml(self, path: Path | str | None = None) -> str:
        text = yaml.safe_dump(self.to_dict(), sort_keys=False)
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimConfig:
        return _build(cls, data, "")

    @classmethod
    def from_yaml(cls, path: Path | str) -> SimConfig:
        try:
            data = load_yaml(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(f"cannot read simulator config {path}: {exc}") from exc
        if not isinstance(data, dict):
            raise ConfigError(f"simulator config {path} is not a mapping")
        try:
            cfg = cls.from_dict(data)
            _check_types(cfg, "")
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from exc
        return cfg


def _type_ok(value: Any, default: Any) -> bool:
    """``value`` has the kind of ``default`` (int or float for a float; a list for a list)."""
    if isinstance(default, bool) or default is None:
        return default is None or isinstance(value, bool)
    if isinstance(default, (int, float)):
        return (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and math.isfinite(float(value))
            and (isinstance(default, float) or isinstance(value, int))
        )
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, list):
        return isinstance(value, list) and _all_numbers(value)
    return True


def _all_numbers(value: Any) -> bool:
    """Every leaf of a (nested) list is a finite int or float."""
    if isinstance(value, list):
        return all(_all_numbers(v) for v in value)
    return (
        isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    )


def _check_types(obj: Any, prefix: str) -> None:
    """Every field of the (nested) dataclass ``obj`` has its default's type (ConfigError)."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            _check_types(value, f"{prefix}{f.name}.")
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        if default is None and f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        if not _type_ok(value, default):
            raise ConfigError(f"{prefix}{f.name} has an invalid value {value!r}")


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    """Dataclass ``cls`` from a (partial) mapping; unknown keys raise ConfigError."""
    known = {f.name: f for f in fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            raise ConfigError(f"unknown simulator config key '{prefix}{key}'")
        default = known[key].default_factory  # type: ignore[misc]
        sub = default() if callable(default) else None
        if dataclasses.is_dataclass(sub) and isinstance(value, dict):
            kwargs[key] = _build(type(sub), value, f"{prefix}{key}.")
        elif dataclasses.is_dataclass(sub):
            raise ConfigError(f"simulator config key '{prefix}{key}' must be a mapping")
        else:
            kwargs[key] = value
    return cls(**kwargs)
