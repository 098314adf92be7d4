"""Options of the INS and its runner: one dataclass per component."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

ModelName = Literal["paper", "biased"]
InitMode = Literal["static", "gps", "groundtruth"]


@dataclass(frozen=True)
class FilterOptions:
    """Sigma points, propagation chunking and gating.

    ``max_predict_steps``: IMU steps propagated between two draws of sigma points (the process
    noise of the chunk is added at its end, see ``models.imu.process_noise``); 1 = textbook UKF.
    ``propagation``: "preintegrated" (increments computed once per chunk, applied to every sigma
    point to first order in its bias/rate offset; fast) or "exact" (every sigma point integrated).
    ``gate_probability``: chi-square gate of every non-vision update (None disables gating).
    ``stack_with_vision``: pass non-vision measurements stamped at a frame time to the vision
    updater (``FrameContext.extra``) instead of fusing them first.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    max_predict_steps: int = 20
    propagation: Literal["preintegrated", "exact"] = "preintegrated"
    gate_probability: float | None = 0.999
    stack_with_vision: bool = False


@dataclass(frozen=True)
class NoiseOptions:
    """IMU noise densities override the data set's ``sensor.yaml`` when not None; scales inflate
    them (real IMUs are worse than their data sheets, and the paper model has no bias states)."""

    gyro_noise_density: float | None = None
    gyro_random_walk: float | None = None
    accel_noise_density: float | None = None
    accel_random_walk: float | None = None
    white_scale: float = 1.0
    random_walk_scale: float = 1.0
    # Paper model only: accelerometer bias is not a state, so its effect is absorbed as extra
    # white acceleration noise (m/s²/√Hz) on v and p.
    paper_extra_accel_density: float = 0.05


@dataclass(frozen=True)
class InitOptions:
    """Initialisation: ``mode`` static (gravity, gyro mean, magnetometer heading), gps (in
    flight: GPS position, velocity and acceleration, specific force, magnetometer heading;
    ``flight_roll_pitch_std`` then) or groundtruth.

    The static interval is the first ``static_s`` seconds. Rotors make a resting vehicle's IMU
    vibrate (EuRoC: 0.3 m/s², 0.08 rad/s sample std), so "static" is tested on the means of
    ``block_s`` blocks: their spread must stay below ``max_accel_dev`` and ``max_gyro_dev``.
    """

    mode: InitMode = "static"
    static_s: float = 2.0
    block_s: float = 0.1
    max_accel_dev: float = 0.3  # m/s², block-mean accelerometer deviation from the mean
    max_gyro_dev: float = 0.05  # rad/s, block-mean gyro deviation from the mean
    position_std: float = 0.1  # m
    velocity_std: float = 0.05  # m/s
    roll_pitch_std: float = 0.02  # rad
    flight_roll_pitch_std: float = 0.05  # rad (in-flight start from GPS)
    yaw_std: float = 0.1  # rad (with magnetometer or ground truth)
    yaw_std_unknown: float = 0.5  # rad (no heading source)
    course_min_speed_mps: float = 3.0  # GPS start without magnetometer: heading from the course
    omega_std: float = 0.01  # rad/s
    gyro_bias_std: float = 0.005  # rad/s
    accel_bias_std: float = 0.1  # m/s²
    # Standard deviations when starting from ground truth (its own error, not the filter's).
    gt_position_std: float = 0.01  # m
    gt_velocity_std: float = 0.01  # m/s
    gt_attitude_std: float = 0.005  # rad
    gt_gyro_bias_std: float = 0.001  # rad/s
    gt_accel_bias_std: float = 0.02  # m/s²


@dataclass(frozen=True)
class RunOptions:
    """Everything ``run_method`` needs besides the data set."""

    model: ModelName = "biased"
    filter: FilterOptions = field(default_factory=FilterOptions)
    noise: NoiseOptions = field(default_factory=NoiseOptions)
    init: InitOptions = field(default_factory=InitOptions)
    use_gps: bool = True
    use_mag: bool = True
    use_sonar: bool = True
    use_gps_velocity: bool = True
    # Fuse magnetometer / sonar samples at most at this rate (None: every sample). A 100 Hz
    # magnetometer adds little over 10 Hz but costs one UKF update per IMU step.
    max_mag_rate_hz: float | None = 10.0
    max_sonar_rate_hz: float | None = 10.0
    output_period_s: float = 0.1  # states.csv / trajectory.tum rate (10 Hz)
    duration_s: float | None = None  # stop after this much data (None: all)
    method_options: dict[str, Any] = field(default_factory=dict)  # for vision methods
