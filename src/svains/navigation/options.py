"""The run configuration: one frozen dataclass tree (``RunConfig``), one dataclass per component.

Every option has one default, here. ``svains.navigation.config_io`` gives the YAML round trip and
``--set section.key=value`` overrides (type-checked, errors name the dotted key).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

from svains.errors import ConfigError
from svains.navigation.option_types import check_types
from svains.navigation.options_smoother import SmootherOptions
from svains.navigation.options_vision import LC_COV_SCALE as LC_COV_SCALE
from svains.navigation.options_vision import LC_COV_SCALE_BUNDLE as LC_COV_SCALE_BUNDLE
from svains.navigation.options_vision import MOTION_MODELS as MOTION_MODELS
from svains.navigation.options_vision import MotionModel as MotionModel
from svains.navigation.options_vision import SourceName as SourceName
from svains.navigation.options_vision import VisionOptions
from svains.navigation.options_zupt import ZuptOptions

ModelName = Literal["paper", "biased"]
InitMode = Literal["static", "gps", "groundtruth", "vision"]
MethodName = Literal["ins", "vo", "lc", "tc", "3d"]


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

    ``alpha`` sets the sigma points' spread, ``alpha sqrt(n)`` standard deviations (n = 18, plus
    6 per pose clone: 4.2 to 5.5 σ at alpha = 1), far outside a Gaussian's mass, where a
    non-linear model (attitude, the vision models' relative pose once a gap or fault has grown
    P) is sampled where it no longer resembles its local shape. The default is the smallest
    spread whose covariance weights all stay non-negative for beta = 2, kappa = 0, whatever n
    (``Wc0 = 4 - alpha² - alpha⁻² >= 0`` for alpha >= sqrt(2 - sqrt(3)) = 0.5176): the predicted
    P stays a positive combination and updates keep the Woodbury gain (``filter.ukf``).
    Measured against alpha = 1 (``bench/faults.py``, 5 s IMU gap, 3d, seeds 0-1 / 2-5: NEES
    after the gap 13.8 / 12.5 -> 10.7 / 11.1, RMSE 1.54x / 2.20x -> 1.25x / 1.88x the clean
    run's; KITTI raw GPS-denied 3d and EuRoC static drift unchanged).
    """

    alpha: float = 0.52
    beta: float = 2.0
    kappa: float = 0.0
    max_predict_steps: int = 20
    propagation: Literal["preintegrated", "exact"] = "preintegrated"
    gate_probability: float | None = 0.999
    stack_with_vision: bool = False


@dataclass(frozen=True)
class NoiseOptions:
    """IMU noise densities override the data set's ``sensor.yaml`` when not None; scales inflate
    them (real IMUs are worse than their data sheets, and the paper model has no bias states).

    ``static_rule``: after a static start, a sensor whose white noise measured at rest (block
    means of ``init.block_s``) exceeds its calibration beyond the estimate's
    ``static_probability`` quantile takes the measured density, and its bias random walk grows
    by the square root of the same ratio (``navigation.platform_noise``). Densities given here
    explicitly are kept.
    """

    gyro_noise_density: float | None = None
    gyro_random_walk: float | None = None
    accel_noise_density: float | None = None
    accel_random_walk: float | None = None
    white_scale: float = 1.0
    random_walk_scale: float = 1.0
    # Paper model only: accelerometer bias is not a state, so its effect is absorbed as extra
    # white acceleration noise (m/s²/√Hz) on v and p.
    paper_extra_accel_density: float = 0.05
    static_rule: bool = True
    static_probability: float = 0.999

    def __post_init__(self) -> None:
        check_types(self, "noise.")
        if not 0 < self.static_probability < 1:
            raise ConfigError(
                f"noise.static_probability must be in (0, 1), got {self.static_probability}"
            )


@dataclass(frozen=True)
class InitOptions:
    """Initialisation: ``mode`` static (gravity, gyro mean, magnetometer heading), gps (in
    flight: GPS position, velocity and acceleration, specific force, magnetometer heading;
    ``flight_roll_pitch_std`` then), vision (in flight without GPS: gravity and velocity from
    the first seconds of stereo odometry against the IMU, ``navigation.vision_start``) or
    groundtruth.

    The static interval is the first ``static_s`` seconds. Rotors make a resting vehicle's IMU
    vibrate (EuRoC: 0.3 m/s², 0.08 rad/s sample std), so "static" is tested on the means of
    ``block_s`` blocks: their spread must stay below ``max_accel_dev`` and ``max_gyro_dev``.
    """

    mode: InitMode = "static"
    static_s: float = 2.0
    # Static start with a GPS in the rig: wait this long after the static interval for the
    # first fix (it sets the start position); without one by then, start at the origin.
    gps_wait_s: float = 10.0
    block_s: float = 0.1
    max_accel_dev: float = 0.3  # m/s², block-mean accelerometer deviation from the mean
    max_gyro_dev: float = 0.05  # rad/s, block-mean gyro deviation from the mean
    position_std: float = 0.1  # m
    velocity_std: float = 0.05  # m/s
    roll_pitch_std: float = 0.02  # rad
    flight_roll_pitch_std: float = 0.05  # rad (in-flight start from GPS)
    # m/s², per axis: the vehicle's acceleration before any measurement, which an acceleration
    # differenced from position-only fixes is shrunk towards zero with (a 1 Hz fix of 1.4 m
    # gives an acceleration of 3.5 m/s² std, a tilt of 20°; ``init._with_start_velocities``)
    flight_accel_prior_std: float = 1.0
    yaw_std: float = 0.1  # rad (with magnetometer or ground truth)
    yaw_std_unknown: float = 0.5  # rad (no heading source, GPS fused: the heading is unknown)
    # rad (no heading source and no GPS fused: the start heading defines the world frame's yaw,
    # a gauge, so its error is zero by construction; kept at the roll/pitch level for the
    # sigma points). With ``yaw_std_unknown`` there, the sigma points sat ±140° apart in an
    # unobservable yaw, and on the static EuRoC micro start the 3d heading wandered by up to
    # 7.5° (RMS 2.2°) while the MAV was at rest (ground truth: 0.19°); 0.27° (0.16°) with this.
    yaw_std_local: float = 0.02
    course_min_speed_mps: float = 3.0  # GPS start without magnetometer: heading from the course
    # rad: ...when the course is known this well (its σ: the velocity noise over the speed,
    # and sideslip); a noisier one is no heading (the heading check's ``max_std_deg``)
    course_max_yaw_std: float = 0.175
    # A static start with GPS fused and no magnetometer (and a ``vision`` start, the fix
    # nearest it placing the body; a ``gps`` start too slow for the course, vision fused):
    # True runs in a local frame (yaw σ ``yaw_std_local``) holding the GPS fixes out until
    # their velocities against the filter's give the heading, then turns the frame and what
    # it logged (``navigation.navigator_core``); False takes an arbitrary heading with
    # ``yaw_std_unknown`` and fuses the fixes at once (a UKF cannot carry a heading known to
    # ±180°: a user's probe, NEES 1650).
    heading_from_gps: bool = True
    # An ``ins`` started from GPS in motion with no heading source (too slow for the course, no
    # magnetometer): this many copies of the filter over the circle of headings, weighed by
    # the fixes and merged once the heading is known to ``yaw_bank_max_std`` rad (one UKF
    # carries that; the copies' own σ were 8-10° after a 90° turn at 2 m/s, which a 10° bound
    # never merged) (``navigation.yaw_bank``); None: the arbitrary heading with
    # ``yaw_std_unknown``, which the first fixes collapsed whatever its error (simulated
    # 2 m/s flights started at 15-45 s: 43-178° off to the end).
    yaw_bank_models: int | None = 8
    yaw_bank_max_std: float = 0.26
    # ``vision`` (in flight, no GPS needed): stereo odometry over the first ``vision_window_s``
    # s against the IMU gives gravity and the velocity (``navigation.vision_start``); the fit's
    # gravity magnitude must lie within ``vision_max_g_error`` (relative) of the data set's.
    vision_window_s: float = 2.0
    vision_max_g_error: float = 0.1
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
class BufferOptions:
    """The Navigator's time-ordered input buffer. A measurement stamped t is processed once an
    IMU sample stamped later than ``t + window_s`` has arrived (so measurements up to
    ``window_s`` late are put back in order); one stamped at or before the last processed time
    is dropped, counted and warned about. ``max_pending`` bounds the waiting measurements.
    ``imu_keep_s``: IMU samples older than this before the previous frame (or the front end's
    reference frame, or now) are let go, so a long online run keeps bounded memory (None: keep
    every sample)."""

    window_s: float = 0.1
    max_pending: int = 100_000
    imu_keep_s: float | None = 60.0


@dataclass(frozen=True)
class ReplayOptions:
    """How ``svains run`` replays a data set (ignored by the Navigator itself): skip the first
    ``start_s`` seconds of the recording; simulate ``features0`` along the ground truth at
    ``synthetic_features_hz`` (None: off); ``calib`` (Kalibr camchain-imucam.yaml) and
    ``imu_calib`` (Kalibr imu.yaml) paths replace the data set's calibration (None: its own);
    ``topics``: a bag's topic per role where auto-detection is ambiguous,
    ``"imu=/imu0,left=/cam0/image_raw"`` (roles imu, left, right, gps, gt; ``--topic``)."""

    start_s: float = 0.0
    synthetic_features_hz: float | None = None
    calib: str | None = None
    imu_calib: str | None = None
    topics: str | None = None


@dataclass(frozen=True)
class FaultOptions:
    """Sensor-fault handling (``RunConfig.faults``; issue 12).

    ``imu_guard``: check every IMU sample (``navigation.imu_guard.ImuGuard``: non-finite,
    all-zero, frozen, saturated and spike samples are dropped and bridged by their neighbours; a
    gap of more than ``imu_gap_factor`` median spacings adds the noise it skipped to the
    covariance,
    ``gap_covariance`` with the sample spread of the ``gap_spread_s`` before it plus the white
    noise of the two samples the bridge is drawn between; vision updates in a gap and 1 s after
    it are linearised ``gap_vision_iterations`` times, ``filter.iterated``, and gated at
    ``gap_vision_gate_probability``; ``tc``/``3d`` there marginalise each point over both frames,
    ``gap_vision_two_view``, since the frames then carry the translation alone and the k-1
    stereo point taken as exact attenuates it).
    ``consistency``: watch every gated update (``navigation.consistency``) and, when the
    filter rejects independent sensors (or GPS alone) with a small covariance, inflate the
    position/velocity/attitude covariance by ``inflate_factor`` or reset position and velocity
    from the next GPS fix. ``vision_max_gap_s``: a vision method that fuses no vision for
    longer is warned about and reported (``vision_gaps``). ``warn_interval_s``: at most one
    warning per kind of event in this much data time (the rest are counted).
    ``bias_test_probability``: GPS innovations that lean one way over ``bias_test_window``
    accepted fixes (a common offset beyond this chi-square quantile; None: no test) widen the
    IMU biases' standard deviations by ``sqrt(bias_widen_factor)``, up to ``bias_max_gyro_std``
    / ``bias_max_accel_std``, and attitude and velocity by what that widening would have done
    over half the window (``fault_handling.step_variances``): a bias step (a knocked IMU) is
    then learnt in seconds instead of being taken for a tilt until GPS is rejected. The widening
    is a step kept as states (``navigation.bias_recall``): unless the biases learnt since leave
    those from before the alarm beyond the ``bias_confirm_probability`` quantile (6 dof; the
    step confirmed), the filter is conditioned on a zero step when the GPS (and the vision
    test's updates, below) falls silent for 2 s or ``bias_confirm_s`` after the alarm, which
    gives back exactly what a filter never widened would hold (None: the widening stays,
    ``fault_handling.widen_biases``). Since false alarms cost only the seconds they are pending
    (a less precise attitude, mostly), the test runs at 0.975 (2.5 % of white windows):
    ``bench/faults.py`` seeds 0-7, after a 0.5 m/s² accelerometer step ``3d`` 1.48x the clean
    RMSE (0.99: 1.67x; without a test 1.98x), NEES 10.8 / 10.3 (0.99: 12.5 / 11.2); clean
    ``ins`` +1.2 % RMSE. 0.95 learns steps faster (``ins`` 1.04x) but costs clean ``ins`` runs
    +2.3 % RMSE and +10 % attitude RMSE (docs/results/faults.md).
    ``bias_test_rate_probability``: a GPS window with velocity alarms only when its velocity
    innovations, whitened on their own, also share an offset beyond this quantile (an IMU
    bias step moves the velocity at once; a GPS position ramping off while its velocity
    agrees is the receiver's fault). None, the default: the position alone may alarm. At 0.9
    on ``bench/faults.py`` seeds 0-7 the GPS ramp's ``3d`` goes 1.63x -> 1.46x clean and every
    ``ins`` row gains, but ``3d`` loses on seed 7 (clean +8 %, gyro step +60 %), whose
    position-only alarms helped (docs/results/faults.md).
    ``bias_test_vision_probability``: in GPS-aided runs the vision updates' corrections of
    velocity and attitude, whitened by the covariance each update removed, feed the same test
    over ``bias_test_vision_window`` accepted frames (``ConsistencyMonitor``; None: off). A
    gyro bias step turns the heading the same way between every two frames: the corrections
    lean within a second or two, long before the GPS innovations do. 0.999, since frames come
    several times a second: on ``bench/faults.py`` seeds 0-7 no false alarm from vision in the
    clean runs (0.975: 8 in 8 runs, clean ``3d`` RMSE +3.4 %); ``3d`` after the
    accelerometer / gyro step 1.48x / 1.08x → 1.20x / 0.94x, NEES 10.3 / 11.6 → 8.8 / 7.6.
    GPS-denied runs take it only with ``bias_test_vision_gps_denied``: there it takes the bias
    steps of ``bench/faults.py`` from 1.89x / 1.35x to 1.14x / 1.03x, but the real EuRoC IMU,
    whose model leans without a step, raises false alarms (4 in 145 s; irregular EuRoC frames
    0.292 → 0.313 m mean ATE on seeds 10-29). ``bias_test_probability`` None turns both off.
    ``gps_jump_hold_s``: for this long after a GPS jump (``ConsistencyMonitor``) a fix inside
    its gate is still refused when its innovation is nearer the jump's than zero
    (``jump_offsets``; None: the gate alone decides, as before): without it the filter's own
    spread, growing while the jumped fixes are refused, lets the offset in (KITTI raw, `ins`,
    every fix 50 m off from 10 s: adopted 24 s later, position RMSE 15.8 m against 11.6 m with
    those fixes removed; now 11.6 m). After the hold the gate decides again: a datum change
    that lasts is taken, warned, once nothing else can hold the filter.
    ``gps_scatter_probability``: GPS rejected alone counts as a lost filter only when its
    innovations since the last accepted fix follow a trend in time (a drifting filter);
    scattered about a quadratic beyond this chi-square quantile (multipath) GPS is distrusted
    instead (``ConsistencyMonitor``, ``_erratic``; None: any three rejections make the filter
    lost, as before): inflated, the filter fused the noise (KITTI raw, `ins`, 10 s of fixes
    with 10 m of noise per axis: 6.99 m position RMSE against 0.51 m with them removed; now
    0.51 m).
    ``gps_velocity_drop_s``: when the velocity of GPS fixes alone disagrees with the filter
    (outside its own gate in three rejected fixes in a row, their position inside its own), GPS
    is fused without its velocity for this long, warned (``drop_rate``; a receiver whose
    Doppler solution failed, a velocity in another frame); None: such fixes are refused whole
    (a velocity 5 m/s off lost GPS for the rest of a KITTI raw run: 11.6 m position RMSE).
    ``lean_test_probability``: the magnetometer's last 5 accepted whitened innovations tested
    for a common offset at this chi-square quantile (``ConsistencyMonitor.leaning``); above
    it the magnetometer is not fused for ``lean_hold_s``, warned (steel nearby turns the field
    by a few degrees: each sample passes its gate and the heading follows; the simulator's
    fault bench, 8° for 10 s, `3d` 11.6x -> 1.7x its clean position RMSE). None: off.
    ``lean_unfuse``: with the hold, the samples in the test's window are taken back
    (``navigation.unfuse``) when vision holds the heading between them (``tc``, ``3d``,
    ``lc``); with the magnetometer the only heading witness (``ins``) a lean is as often the
    disturbance's end, the filter having followed it (two of the bench's eight seeds).
    ``heading_check``: compare the filter's velocity changes between GPS fixes with the GPS's
    and, when a rotation about the vertical maps one onto the other beyond the noise, turn the
    state by it, warned (``navigation.heading_check``: a heading taken from a magnetometer
    whose ``T_BS`` is off, which no other action mends).
    ``gps_latency_check``: find the shift of the GPS stamps that best matches the fixes'
    velocity changes to the IMU's and warn of 40 ms or more with the ``timeshift_gps_imu`` to
    give (``navigation.gps_latency``; a receiver stamped on arrival); it only warns.
    """

    imu_guard: bool = True
    imu_gap_factor: float = 10.0  # median IMU spacings: a longer spacing is a gap
    imu_drop_frozen: bool = True  # drop held IMU readings (off for a coarse IMU at rest)
    gap_vision_iterations: int = 3  # vision update linearisations in and 1 s after a gap
    gap_vision_gate_probability: float = 0.9999999  # the vision update's gate there
    gap_vision_two_view: bool = True  # tc/3d there: each point marginalised over both frames
    gap_spread_s: float = 1.0  # s of samples before a gap whose spread sizes its covariance
    consistency: bool = True
    inflate_factor: float = 100.0  # variance factor on the p/v/θ block at an inflation
    vision_max_gap_s: float = 2.0  # s without a fused vision update before it is a gap
    warn_interval_s: float = 1.0  # s of data time between two warnings of one kind
    bias_test_probability: float | None = 0.975  # None turns the bias-step test off
    bias_test_window: int = 3  # accepted GPS fixes
    bias_test_rate_probability: float | None = None  # 0.9: the GPS velocity must lean too
    bias_widen_factor: float = 1e4  # variance factor on the IMU biases at a bias alarm
    bias_max_gyro_std: float = 0.05  # rad/s, the widening stops here
    bias_max_accel_std: float = 1.0  # m/s², the widening stops here
    bias_confirm_s: float | None = 10.0  # s after an alarm, the old biases are recalled
    bias_confirm_probability: float = 0.999  # their gate: inside it, no step happened
    bias_test_vision_probability: float | None = 0.999  # None: vision updates feed no test
    bias_test_vision_window: int = 3  # accepted vision updates
    bias_test_vision_gps_denied: bool = False  # the vision test in GPS-denied runs too
    gps_jump_hold_s: float | None = 60.0  # s a GPS jump's offset refuses fixes nearer it
    gps_scatter_probability: float | None = 1 - 1e-6  # None: no multipath test
    gps_velocity_drop_s: float | None = 30.0  # s without a GPS velocity that alone disagrees
    lean_test_probability: float | None = 0.9999  # magnetometer lean test (None: off)
    lean_hold_s: float = 10.0  # s a leaning magnetometer is not fused
    lean_unfuse: bool = True  # and its leaning samples taken back (vision methods)
    heading_check: bool = True  # turn a heading the GPS velocity changes show wrong
    gps_latency_check: bool = True  # warn of GPS stamps late against the IMU's clock

    def __post_init__(self) -> None:
        check_types(self, "faults.")
        if not self.imu_gap_factor > 1:
            raise ConfigError(f"faults.imu_gap_factor must be > 1, got {self.imu_gap_factor}")
        if not 0 < self.gap_vision_gate_probability < 1:
            raise ConfigError("faults.gap_vision_gate_probability must be in (0, 1), got "
                              f"{self.gap_vision_gate_probability}")  # fmt: skip
        if self.gap_vision_iterations < 1:
            raise ConfigError(
                f"faults.gap_vision_iterations must be >= 1, got {self.gap_vision_iterations}"
            )
        if not self.inflate_factor >= 1:
            raise ConfigError(f"faults.inflate_factor must be >= 1, got {self.inflate_factor}")
        if not self.vision_max_gap_s > 0:
            raise ConfigError(
                f"faults.vision_max_gap_s must be positive, got {self.vision_max_gap_s}"
            )
        p = self.bias_test_probability
        if p is not None and not 0 < p < 1:
            raise ConfigError(f"faults.bias_test_probability must be in (0, 1) or null, got {p}")
        c = self.bias_confirm_s
        if c is not None and not (math.isfinite(c) and c > 0):
            raise ConfigError(f"faults.bias_confirm_s must be positive or null, got {c}")
        if not 0 < self.bias_confirm_probability < 1:
            raise ConfigError("faults.bias_confirm_probability must be in (0, 1), got "
                              f"{self.bias_confirm_probability}")  # fmt: skip
        p = self.bias_test_rate_probability
        if p is not None and not 0 < p < 1:
            raise ConfigError(
                f"faults.bias_test_rate_probability must be in (0, 1) or null, got {p}"
            )
        p = self.bias_test_vision_probability
        if p is not None and not 0 < p < 1:
            raise ConfigError(
                f"faults.bias_test_vision_probability must be in (0, 1) or null, got {p}"
            )
        for key in ("bias_test_window", "bias_test_vision_window"):
            if getattr(self, key) < 2:
                raise ConfigError(f"faults.{key} must be >= 2, got {getattr(self, key)}")
        if not self.bias_widen_factor >= 1:
            raise ConfigError(
                f"faults.bias_widen_factor must be >= 1, got {self.bias_widen_factor}"
            )
        if not (self.bias_max_gyro_std > 0 and self.bias_max_accel_std > 0):
            raise ConfigError("faults.bias_max_gyro_std and bias_max_accel_std must be positive")
        h = self.gps_jump_hold_s
        if h is not None and not (math.isfinite(h) and h > 0):
            raise ConfigError(f"faults.gps_jump_hold_s must be positive or null, got {h}")
        p = self.lean_test_probability
        if p is not None and not 0 < p < 1:
            raise ConfigError(f"faults.lean_test_probability must be in (0, 1) or null, got {p}")
        if not (math.isfinite(self.lean_hold_s) and self.lean_hold_s > 0):
            raise ConfigError(f"faults.lean_hold_s must be positive, got {self.lean_hold_s}")
        d = self.gps_velocity_drop_s
        if d is not None and not (math.isfinite(d) and d > 0):
            raise ConfigError(f"faults.gps_velocity_drop_s must be positive or null, got {d}")
        p = self.gps_scatter_probability
        if p is not None and not 0 < p < 1:
            raise ConfigError(
                f"faults.gps_scatter_probability must be in (0, 1) or null, got {p}"
            )


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs besides the sensors' calibrations (``svains.sensors.types.Rig``)
    and their measurements.

    ``duration_s``: stop this long after the initial state (None: at the end of the data).
    ``gps_outages``: ``(start_s, duration_s)`` windows, seconds from the first IMU sample the
    Navigator receives, in which GPS fixes are not fused; ``gps_until_s``: no GPS fix after
    this time (same origin); both reproduce the paper's outage experiment on any data set.
    """

    method: MethodName = "ins"
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
    gps_outages: tuple[tuple[float, float], ...] = ()
    gps_until_s: float | None = None
    output_period_s: float = 0.1  # states.csv / trajectory.tum rate (10 Hz)
    duration_s: float | None = None  # stop after this much data (None: all)
    vision: VisionOptions = field(default_factory=VisionOptions)
    buffer: BufferOptions = field(default_factory=BufferOptions)
    replay: ReplayOptions = field(default_factory=ReplayOptions)
    faults: FaultOptions = field(default_factory=FaultOptions)
    zupt: ZuptOptions = field(default_factory=ZuptOptions)
    smoother: SmootherOptions = field(default_factory=SmootherOptions)

    def __post_init__(self) -> None:
        if self.method not in ("ins", "vo", "lc", "tc", "3d"):
            raise ConfigError(f"method must be ins, vo, lc, tc or 3d, got {self.method!r}")
        if self.model not in ("paper", "biased"):
            raise ConfigError(f"model must be paper or biased, got {self.model!r}")
        if self.init.mode not in ("static", "gps", "groundtruth", "vision"):
            raise ConfigError(
                f"init.mode must be static, gps, groundtruth or vision, got {self.init.mode!r}"
            )
        check_types(self, "")
        _check_numbers(self, "")
        if not self.output_period_s >= MIN_OUTPUT_PERIOD_S:
            raise ConfigError(f"output_period_s must be at least {MIN_OUTPUT_PERIOD_S} s (outputs "
                              f"at 1 kHz at most), got {self.output_period_s}")  # fmt: skip
        for start, length in self.gps_outages:
            if length < 0:
                raise ConfigError(f"gps_outages: negative duration {length} at {start} s")
        if self.smoother.enabled and self.vision.consider_extrinsics_std_deg is not None:
            # The RTS pass over a Schmidt forward run is no smoother: a review's simulated
            # flight went 0.111 m forward -> 0.163 m "smoothed", and a linear toy's smoothed
            # variances exceeded the filter's.
            raise ConfigError(
                "smoothing (--smooth) does not handle vision.consider_extrinsics_std_deg yet: "
                "the backward pass over a run with consider parameters can end worse than the "
                "forward run; drop one of the two")


# The name before the typed configuration (``svains.evaluation.run.run_method`` callers).
RunOptions = RunConfig


MIN_OUTPUT_PERIOD_S = 1e-3
# Ranges by the option's name, checked for every section (``_check_numbers``): a name ending in
# one of these is a quantity that cannot be zero (a standard deviation, a noise density, a rate,
# a scale or inflation factor), cannot be negative (a duration, a random walk, a pixel or metre
# bound), or a probability.
_POSITIVE_SUFFIXES = ("_std", "_std_deg", "_std_ms", "_std_mps", "_noise_density", "_scale",
                      "_hz", "_factor", "_inflation")  # fmt: skip
_NON_NEGATIVE_SUFFIXES = ("_s", "_walk", "_density", "_px", "_dev", "_mps", "_drift", "_error",
                          "_fraction", "_max", "_dof", "_m")  # fmt: skip
_POSITIVE = {"filter.alpha", "vision.lc_min_std", "vision.motion_prior_min_std"}
_NON_NEGATIVE = {"filter.beta"}
# Every ``*_probability`` option is the quantile of a test that consistent data pass with that
# probability: below one half a gate refuses most good measurements (``filter.gate_probability``
# 1e-4 refused every update and the run diverged into a numerical error naming no option).
MIN_TEST_PROBABILITY = 0.5
# n + kappa > 0 for the smallest state (position, velocity, attitude: 9), so that the sigma
# points' n + lambda = alpha² (n + kappa) is positive for every state.
_MIN_KAPPA = -9.0


def _check_numbers(obj: object, prefix: str) -> None:
    """Refuse (``ConfigError`` naming the dotted key) a non-finite number in any option of
    ``obj`` and its sections, and a number outside its range by the option's name: ``*_probability``
    in [0.5, 1), the ``_POSITIVE_SUFFIXES`` above zero, the ``_NON_NEGATIVE_SUFFIXES`` not below
    it (None stays allowed where the option is optional)."""
    for f in dataclasses.fields(obj):  # type: ignore[arg-type]
        key, value = prefix + f.name, getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            _check_numbers(value, key + ".")
            continue
        numbers = _floats(value)
        if not numbers:
            continue
        if not all(math.isfinite(v) for v in numbers):
            raise ConfigError(f"{key} must be finite, got {value!r}")
        if key.endswith("_probability") and not all(MIN_TEST_PROBABILITY <= v < 1
                                                    for v in numbers):  # fmt: skip
            raise ConfigError(f"{key} must be a probability in [{MIN_TEST_PROBABILITY:g}, 1) "
                              "(the share of consistent data its test passes), got "
                              f"{value!r}")  # fmt: skip
        if (key in _POSITIVE or key.endswith(_POSITIVE_SUFFIXES)) and min(numbers) <= 0:
            raise ConfigError(f"{key} must be positive, got {value!r}")
        if (key in _NON_NEGATIVE or key.endswith(_NON_NEGATIVE_SUFFIXES)) and min(numbers) < 0:
            raise ConfigError(f"{key} must not be negative, got {value!r}")
        if key == "filter.kappa" and not value > _MIN_KAPPA:
            raise ConfigError(f"filter.kappa must be above {_MIN_KAPPA:g} (the sigma points need "
                              f"n + kappa > 0 for a 9-dof state), got {value!r}")  # fmt: skip


def _floats(value: object) -> list[float]:
    """The numbers of an option's value (an int or float, or a tuple of them, nested; bools
    are not numbers here)."""
    if isinstance(value, bool) or value is None:
        return []
    if isinstance(value, (int, float)):
        return [float(value)]
    if isinstance(value, tuple):
        return [v for item in value for v in _floats(item)]
    return []
