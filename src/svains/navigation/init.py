"""Initial state and covariance: from a static IMU interval, in flight from GPS (+ magnetometer),
or from ground truth.

The functions read an ``InitData`` (the first IMU samples, magnetometer and GPS samples, the
calibrations): the Navigator builds it from what it has received, a replay from a data set.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.errors import ConfigError, InitialisationError, StartFixesRefusedError
from svains.geometry.rotation import quat_normalize, rotmat_to_quat
from svains.models.imu import stencil_consistent_rate
from svains.models.state import BA, BG, DBA, DBG, DP, DTH, DV, DW, P, Q, StateLayout, V, W
from svains.navigation.heading import course_heading_or_none
from svains.navigation.heading_check import horizontal
from svains.navigation.imu_history import gyro_attitudes
from svains.navigation.options import InitOptions
from svains.navigation.platform_noise import measure_static_noise, rest_deviations, rest_window
from svains.navigation.vision_start import VisionInertialFit
from svains.sensors.types import GpsCalib, GroundTruth, ImuCalib, MagCalib
from svains.sensors.units import accel_units_problem

if TYPE_CHECKING:
    from svains.navigation.outputs import NavState

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)

# At rest the specific force is gravity plus the accelerometer's bias and scale error; a
# consumer MEMS part stays within a few percent, a unit mistake (g, gravity removed) does not.
STATIC_GRAVITY_TOL = 0.25
# ``InitialState.info["heading"]`` of a start whose heading the GPS will give (its velocities,
# or the fixes' path; ``InitOptions.heading_from_gps``): it runs in a local frame until then.
HEADING_FROM_GPS = "none (local frame until the GPS gives it)"
# ``InitialState.info`` key of an in-motion start in such a local frame: its horizontal speed
# (m/s), the direction unknown there.
VELOCITY_UNKNOWN = "start_speed_horizontal_mps"
# ``report.json`` ``init.heading`` of a start with no heading source, fixes fused at once
ARBITRARY = "none (arbitrary yaw)"
# ... and of such an ``ins`` start in motion, which runs a bank of headings instead
# (``navigation.yaw_bank``)
HEADING_BANK = "none (a bank of headings until the GPS fixes show it)"
# An in-flight start's fixes whose specific force is this many standard deviations from the
# accelerometer's are refused (``_from_gps``)
START_FORCE_SIGMAS = 3.0
# ... and whose positions are apart by more than their velocities moved the antenna, at this
# chi-square probability (3 dof; 3σ's two-sided probability)
START_FIX_PROBABILITY = 0.9973


@dataclass
class InitialState:
    """Filter start: time ``t_ns`` (an IMU sample time; else the first sample after it, up to
    ``GIVEN_START_MAX_S`` later), state ``x`` (nx,), covariance ``P``."""

    t_ns: int
    x: F64
    P: F64
    info: dict[str, object] = field(default_factory=dict)

    @classmethod
    def from_nav_state(cls, state: NavState) -> InitialState:
        """The start a new Navigator takes to go on from ``state`` (a ``Navigator.state()``
        or an output): a process restarted mid-flight (``init.mode: groundtruth``)."""
        parts = [state.p_W_B, state.v_W_B, state.q_W_B_wxyz, state.omega_B]
        if state.bg_B is not None and state.ba_B is not None:
            parts += [state.bg_B, state.ba_B]
        return cls(int(state.t_ns), np.concatenate(parts).astype(float),
                   np.array(state.P, dtype=float), {"mode": "given", "from": "NavState"})


# A given start's quaternion is normalised when its norm is this close to 1 (a file's rounded
# digits), refused when further off (a norm of 3 ran on, logged as it was: a user's probe).
GIVEN_QUAT_NORM_TOL = 1e-3


def checked_given(given: InitialState, layout: StateLayout) -> InitialState:
    """``given`` with its quaternion normalised; ``ConfigError`` naming the problem when its
    mean is not ``layout``'s size, holds a non-finite number, or its quaternion is not a unit
    one to ``GIVEN_QUAT_NORM_TOL``."""
    x = np.asarray(given.x, dtype=float).ravel()
    if x.size != layout.nx:
        parts = "p, v, q_wxyz, ω" + (", bg, ba" if layout.biased else "")
        raise ConfigError(f"initial_state: x has {x.size} numbers, the state {layout.nx} "
                          f"({parts})")
    if not np.all(np.isfinite(x)):
        raise ConfigError(f"initial_state: x holds a non-finite number: {x.tolist()}")
    norm = float(np.linalg.norm(x[Q]))
    if abs(norm - 1.0) > GIVEN_QUAT_NORM_TOL:
        raise ConfigError(f"initial_state: the attitude q_W_B_wxyz {x[Q].tolist()} has norm "
                          f"{norm:.6g}, not 1 (a unit quaternion, w first)")
    x = x.copy()
    x[Q] = x[Q] / norm
    return InitialState(int(given.t_ns), x, np.asarray(given.P, dtype=float), dict(given.info))


# A given start whose time is no IMU sample's starts at the first sample after it when that
# comes at most this late (s), its position carried on by its velocity (a restarted process
# fed the samples after the saved state's: "the initial time must be an IMU sample time").
GIVEN_START_MAX_S = 0.05


def given_at_sample(given: InitialState, t_imu_ns: NDArray[np.int64]) -> InitialState:
    """``given`` at an IMU sample time of ``t_imu_ns`` (increasing, its last at or after
    ``given.t_ns``): itself at its own sample, else moved to the first sample after it."""
    k = int(np.searchsorted(t_imu_ns, given.t_ns))
    t_k = int(t_imu_ns[k])
    if t_k == given.t_ns:
        return given
    dt_s = (t_k - given.t_ns) * 1e-9
    if dt_s > GIVEN_START_MAX_S:
        raise InitialisationError(
            f"the initial state's time {given.t_ns} ns is no IMU sample's and the first sample "
            f"after it comes {dt_s:.3f} s later ({t_k} ns): feed an IMU sample stamped at the "
            f"initial state's time, or start from a state at most {GIVEN_START_MAX_S} s before "
            "the first sample fed")  # fmt: skip
    x = np.array(given.x, dtype=float)
    x[P] += x[V] * dt_s
    log.info("the initial state (%d ns) is no IMU sample's: the filter starts at the next "
             "sample, %.1f ms later, its position carried on by its velocity", given.t_ns,
             dt_s * 1e3)  # fmt: skip
    return InitialState(t_k, x, np.array(given.P, dtype=float), dict(given.info))


@dataclass(frozen=True)
class ImuArrays:
    """IMU samples ``t_ns`` (N,), ``gyro_B`` and ``accel_B`` (N, 3), in the sensor frame S
    despite the names (the data sets' convention; ``ImuCalib.T_B_S`` rotates them)."""

    t_ns: NDArray[np.int64]
    gyro_B: F64
    accel_B: F64


@dataclass(frozen=True)
class MagArrays:
    t_ns: NDArray[np.int64]
    m_S: F64


@dataclass(frozen=True)
class GpsArrays:
    t_ns: NDArray[np.int64]
    p_W_G: F64
    v_W_G: F64


@dataclass(frozen=True)
class InitData:
    """What an initialisation reads (the attribute names of a data set's streams)."""

    name: str
    gravity_W: tuple[float, float, float]
    imu: ImuArrays | None
    imu_calib: ImuCalib | None = None
    mag: MagArrays | None = None
    mag_calib: MagCalib | None = None
    gps: GpsArrays | None = None
    gps_calib: GpsCalib | None = None
    groundtruth: GroundTruth | None = None
    # Whether the run fuses GPS (None: whenever ``gps_calib`` is given). Without GPS and without
    # a heading source the world frame is local and its yaw is defined by the start.
    gps_fused: bool | None = None
    # Whether the run can hold an in-motion start in a local frame until the GPS gives the
    # heading (``_from_gps``): it fuses vision, which measures the velocity there, and its
    # heading check is on (off, the wait ends at once).
    local_heading_wait: bool = False


def _triad(a_B: F64, b_B: F64, a_W: F64, b_W: F64) -> F64:
    """``R_W_B`` aligning body vectors with world vectors (a exactly, b in the a-b plane)."""

    def frame(a: F64, b: F64) -> F64:
        e1 = a / np.linalg.norm(a)
        e2 = np.cross(a, b)
        n2 = np.linalg.norm(e2)
        if n2 < 1e-9:
            raise InitialisationError("magnetic field is parallel to gravity: no heading")
        e2 /= n2
        return np.column_stack([e1, e2, np.cross(e1, e2)])

    return frame(a_W, b_W) @ frame(a_B, b_B).T


def _align_up(up_B: F64, up_W: F64) -> F64:
    """Smallest rotation ``R_W_B`` with ``R_W_B up_B = up_W`` (heading left arbitrary)."""
    a = up_B / np.linalg.norm(up_B)
    axis = np.cross(a, up_W)
    s = np.linalg.norm(axis)
    c = float(a @ up_W)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _covariance(layout: StateLayout, stds: list[tuple[slice, object]]) -> F64:
    P0 = np.zeros((layout.ndx, layout.ndx))
    for sl, std in stds:
        if sl.start < layout.ndx:
            P0[sl, sl] = np.diag(np.broadcast_to(np.asarray(std, dtype=float), (3,)) ** 2)
    return P0


def initialise(
    dataset: InitData, layout: StateLayout, options: InitOptions, t_start_ns: int | None = None
) -> InitialState:
    """Initial state per ``options.mode``; ``InitialisationError`` when the data cannot give one.

    ``t_start_ns`` (ground-truth mode only): start at the first IMU sample at or after it instead
    of at the start of the ground truth.
    """
    if dataset.imu is None or len(dataset.imu.t_ns) < 3:
        raise InitialisationError(f"{dataset.name}: no IMU stream (at least 3 samples needed)")
    if options.mode == "groundtruth":
        return _from_groundtruth(dataset, layout, options, t_start_ns)
    if options.mode == "static":
        return _from_static(dataset, layout, options)
    if options.mode == "gps":
        # In flight nothing rests to compare with gravity; the samples so far still show a
        # unit mistake (a static start compares its mean, ``STATIC_GRAVITY_TOL``).
        problem = accel_units_problem(dataset.imu.accel_B, np.asarray(dataset.gravity_W),
                                      dataset.imu.gyro_B)  # fmt: skip
        if problem is not None:
            raise InitialisationError(f"{dataset.name}: {problem}")
        return _from_gps(dataset, layout, options)
    raise InitialisationError(f"unknown init mode {options.mode!r} (static|gps|groundtruth)")


def _imu_R_B_S(dataset: InitData) -> F64:
    return np.eye(3) if dataset.imu_calib is None else dataset.imu_calib.T_B_S[:3, :3]


def _from_static(dataset: InitData, layout: StateLayout, o: InitOptions) -> InitialState:
    imu = dataset.imu
    assert imu is not None
    # Start at the third sample so the stencil of eq. 3 has its history.
    t0 = int(imu.t_ns[2])
    n, dt_s, n_block = rest_window(imu.t_ns, o.static_s, o.block_s)
    if n < 10:
        raise InitialisationError(
            f"static interval of {o.static_s} s holds {n} IMU samples (need >= 10)"
        )
    R_B_S = _imu_R_B_S(dataset)
    gyro = imu.gyro_B[:n] @ R_B_S.T
    acc = imu.accel_B[:n] @ R_B_S.T
    if len(acc) // n_block < 2:
        raise InitialisationError(f"static interval of {o.static_s} s is shorter than two blocks")
    acc_dev, gyro_dev = rest_deviations(gyro, acc, n_block)
    if acc_dev > o.max_accel_dev or gyro_dev > o.max_gyro_dev:
        # A turn tilts gravity in the accelerometer unless it is about the vertical; a gyro
        # that wanders under a steady accelerometer is more often one read in deg/s. But a
        # multicopter's accelerometer stays steady as it banks (its thrust turns with it), so
        # the hint gives the turn for the user to judge (a MAV turning 16°/s at EuRoC's 10 s
        # was asked about deg/s alone: a user's probe).
        hint = (f"; the accelerometer is steady: if the vehicle did not turn (the gyro reads "
                f"{np.degrees(gyro_dev):.0f}°/s in rad/s), is the gyro in deg/s? (svains reads "
                "rad/s)" if acc_dev <= o.max_accel_dev else "")  # fmt: skip
        raise InitialisationError(
            f"IMU is not static during the first {o.static_s} s: {o.block_s} s block means "
            f"deviate by up to {acc_dev:.3f} m/s² (max {o.max_accel_dev}) and {gyro_dev:.4f} "
            f"rad/s (max {o.max_gyro_dev}); to start in motion use --init vision (stereo) or "
            f"--init gps, or --init groundtruth{hint}"
        )
    f_B = acc.mean(axis=0)
    bg = gyro.mean(axis=0)
    g_W = np.asarray(dataset.gravity_W, dtype=float)
    f_norm, g_norm = float(np.linalg.norm(f_B)), float(np.linalg.norm(g_W))
    if abs(f_norm / g_norm - 1.0) > STATIC_GRAVITY_TOL:
        raise InitialisationError(
            f"at rest the accelerometer reads {f_norm:.4g} m/s² against gravity {g_norm:.4g} "
            "m/s²: is it in g, or with gravity removed? (svains reads specific force in m/s², "
            "gravity included)"
        )
    up_W = -g_W / np.linalg.norm(g_W)
    info: dict[str, object] = {
        "mode": "static",
        "static_samples": n,
        "accel_block_dev": acc_dev,
        "gyro_block_dev": gyro_dev,
        # The platform's white noise at rest (``navigation.platform_noise``).
        "static_noise": measure_static_noise(gyro, acc, dt_s, o.block_s).as_dict(),
    }
    yaw_std = o.yaw_std_unknown
    mag_sel = None
    if dataset.mag is not None and dataset.mag_calib is not None:
        mag_sel = dataset.mag.t_ns - t0 <= int(o.static_s * 1e9)
    if mag_sel is not None and mag_sel.any():
        assert dataset.mag is not None and dataset.mag_calib is not None
        m_B = dataset.mag_calib.T_B_S[:3, :3] @ dataset.mag.m_S[mag_sel].mean(axis=0)
        R_W_B = _triad(f_B, m_B, up_W, np.asarray(dataset.mag_calib.m_W, dtype=float))
        yaw_std = o.yaw_std
        info["heading"] = "magnetometer"
    else:
        R_W_B = _align_up(f_B, up_W)
        gps_fused = getattr(dataset, "gps_fused", None)  # a Dataset has no such field
        if gps_fused is None:
            gps_fused = dataset.gps_calib is not None
        if gps_fused and o.heading_from_gps:
            yaw_std = o.yaw_std_local
            info["heading"] = HEADING_FROM_GPS
            log.warning("no magnetometer in the static interval: the heading is taken from the "
                        "GPS (its velocities, or its path) once the vehicle moves; GPS fixes "
                        "wait for it")  # fmt: skip
        elif gps_fused:
            info["heading"] = ARBITRARY
            log.warning("no magnetometer in the static interval: heading starts arbitrary")
        else:
            yaw_std = o.yaw_std_local
            info["heading"] = "none (local frame: the start defines its yaw)"
    x = np.zeros(layout.nx)
    x[Q] = quat_normalize(rotmat_to_quat(R_W_B))
    position_std = o.position_std
    if dataset.gps is not None and dataset.gps_calib is not None and len(dataset.gps.t_ns):
        # The fixes of the static interval (at least the first): their median (one fix off
        # among three does not move it), uncertain by a fix's noise (GPS errors are correlated
        # over seconds, so not divided by their count). With the option's 0.1 m a first fix 5 m
        # off (a 1.4 m receiver) was taken as exact: the right fixes after it were refused as
        # jumps and `ins` ended 1.5 km off.
        in_static = dataset.gps.t_ns - int(imu.t_ns[0]) <= int(o.static_s * 1e9)
        in_static[0] = True
        x[P] = np.median(dataset.gps.p_W_G[in_static], axis=0) - R_W_B @ dataset.gps_calib.p_B_G
        position_std = max(position_std, dataset.gps_calib.position_noise_std)
        n_fixes = int(in_static.sum())
        info["position"] = f"median of the {n_fixes} GPS fixes at rest" if n_fixes > 1 else (
            "first GPS fix")
    if layout.biased:
        x[BG] = bg
        info["gyro_bias_B"] = bg.tolist()
    # Static: the true rate is zero. The paper model's ω follows the gyro's changes from ω_0;
    # starting it at the stencil-consistent gyro value minus the bias keeps it offset-free.
    k0 = min(2, len(gyro) - 1)
    x[W] = 0.0 if layout.biased else stencil_consistent_rate(gyro, k0) - bg
    P0 = _levelled_covariance(layout, o, R_W_B, up_W, position_std, o.velocity_std,
                              o.roll_pitch_std, yaw_std)  # fmt: skip
    return InitialState(t0, x, P0, info)


def _levelled_covariance(
    layout: StateLayout, o: InitOptions, R_W_B: F64, up_W: F64, position_std: float,
    velocity_std: float, roll_pitch_std: float, yaw_std: float,
) -> F64:
    """Start covariance of a start levelled from the specific force (static or in flight):
    the given position/velocity std, the attitude std as (roll, pitch, yaw) about world axes
    rotated to body axes (for a z-vertical world), rate and bias std from ``o``."""
    P0 = _covariance(
        layout,
        [
            (DP, position_std),
            (DV, velocity_std),
            (DTH, np.array([roll_pitch_std, roll_pitch_std, yaw_std])),
            (DW, o.omega_std),
            (DBG, o.gyro_bias_std),
            (DBA, o.accel_bias_std),
        ],
    )
    if _is_z_vertical(up_W):
        P0[DTH, DTH] = R_W_B.T @ P0[DTH, DTH] @ R_W_B
    return P0


def _is_z_vertical(up_W: F64) -> bool:
    return abs(abs(up_W[2]) - 1.0) < 1e-9


def _from_groundtruth(
    dataset: InitData, layout: StateLayout, o: InitOptions, t_start_ns: int | None = None
) -> InitialState:
    gt = dataset.groundtruth
    imu = dataset.imu
    assert imu is not None
    if gt is None or len(gt.t_ns) == 0:
        raise InitialisationError(f"{dataset.name}: --init groundtruth needs a ground-truth stream")
    t_first = int(gt.t_ns[0]) if t_start_ns is None else max(int(gt.t_ns[0]), int(t_start_ns))
    # At least the third IMU sample, so the stencil of eq. 3 has its history.
    k = max(2, int(np.searchsorted(imu.t_ns, t_first)))
    if k >= len(imu.t_ns) - 2 or t_first > gt.t_ns[-1]:
        raise InitialisationError("no IMU and ground truth overlap after the requested start")
    t0 = int(imu.t_ns[k])
    j = int(np.clip(np.searchsorted(gt.t_ns, t0), 1, len(gt.t_ns) - 1))
    s = float((t0 - gt.t_ns[j - 1]) / max(1, gt.t_ns[j] - gt.t_ns[j - 1]))
    s = min(max(s, 0.0), 1.0)

    def lerp(a: F64) -> F64:
        return (1 - s) * a[j - 1] + s * a[j]

    x = np.zeros(layout.nx)
    x[P] = lerp(gt.p_W_B)
    x[V] = lerp(gt.v_W_B)
    q0, q1 = gt.q_W_B_wxyz[j - 1], gt.q_W_B_wxyz[j]
    x[Q] = quat_normalize((1 - s) * q0 + s * (q1 if q0 @ q1 >= 0 else -q1))
    R_B_S = _imu_R_B_S(dataset)
    bg = lerp(gt.bg_B)
    gyro_B = imu.gyro_B[max(0, k - 2) : k + 1] @ R_B_S.T
    # Paper model: ω is integrated from the stencil α, so start it offset-free (see
    # stencil_consistent_rate); the biased model re-reads the gyro at every sample anyway.
    g_k = gyro_B[-1] if layout.biased else stencil_consistent_rate(gyro_B, len(gyro_B) - 1)
    x[W] = g_k - bg
    if layout.biased:
        x[BG] = bg
        x[BA] = lerp(gt.ba_B)
    P0 = _covariance(
        layout,
        [
            (DP, o.gt_position_std),
            (DV, o.gt_velocity_std),
            (DTH, o.gt_attitude_std),
            (DW, o.omega_std),
            (DBG, o.gt_gyro_bias_std),
            (DBA, o.gt_accel_bias_std),
        ],
    )
    return InitialState(t0, x, P0, {"mode": "groundtruth"})


# m/s² per axis: the acceleration noise an in-flight start's fixes with velocities may carry
# from differencing those velocities (√2 σ_v / Δt; 0.15 tilts the start 0.9°, as 1 Hz fixes
# of σ_v 0.1 m/s do): the next fix of a 50 Hz GPS (7 m/s² differenced) started a simulated
# flight 24° tilted and 49° off in heading with a σ of 3°, NEES 160-660 (a probe).
# ``start_fixes`` spaces them for it.
START_ACCEL_NOISE_MPS2 = 0.15
# s: the spacing a start's fixes need for that at most (and that of position-only fixes,
# whose differenced velocities and acceleration are poor at any spacing a start can wait).
START_MAX_SPACING_S = 1.0
# A fix this fraction short of that spacing still serves: a 1 Hz receiver's stamps jitter
# (KITTI raw: 0.93-1.04 s), and its next fix is the one meant.
START_SPACING_SLACK = 0.2


def start_fix_spacing_s(velocity_noise_std: float, with_velocity: bool) -> float:
    """The spacing (s) ``start_fixes`` keeps between an in-flight start's fixes: that which
    brings their differenced velocities' noise ``velocity_noise_std`` (m/s) down to
    ``START_ACCEL_NOISE_MPS2``, at most ``START_MAX_SPACING_S`` (always, without velocities)."""
    if not with_velocity:
        return START_MAX_SPACING_S
    return min(START_MAX_SPACING_S, np.sqrt(2.0) * velocity_noise_std / START_ACCEL_NOISE_MPS2)


def start_fixes(gps: GpsArrays, velocity_noise_std: float) -> tuple[GpsArrays, bool]:
    """The fixes an in-flight start takes from ``gps`` (time-ordered) and whether ``gps`` had
    them: two with velocities (when the first fix has one and enough later ones do; else
    three positions), the first, then each the one nearest ``start_fix_spacing_s`` after the
    one before, not more than ``START_SPACING_SLACK`` short of it. Past a gap over twice the
    spacing the fix before the gap serves when it is that near, else the one after it, as a
    slow receiver's next fix does (the fix 20 ms from the first, then an outage, started
    26-131° tilted; restarting after each gap never started fixes in bursts: reviews). Not
    had: the first two (three) fixes as they came."""
    if len(gps.t_ns) and np.all(np.isfinite(gps.v_W_G[0])):
        got = _spaced(gps, velocity_noise_std, True)
        if got[1]:
            return got
        positions = _spaced(gps, velocity_noise_std, False)
        # a receiver whose later fixes lack the first's velocity waited for ever (a review)
        return positions if positions[1] else got
    return _spaced(gps, velocity_noise_std, False)


def _spaced(gps: GpsArrays, velocity_noise_std: float, with_v: bool) -> tuple[GpsArrays, bool]:
    n = 2 if with_v else 3
    spacing_ns = int(start_fix_spacing_s(velocity_noise_std, with_v) * 1e9)
    least_ns = int((1.0 - START_SPACING_SLACK) * spacing_ns)
    usable = np.all(np.isfinite(gps.v_W_G), axis=1) if with_v else np.ones(len(gps.t_ns), bool)
    picked = [0] if len(gps.t_ns) and usable[0] else []
    while picked and len(picked) < n:
        t_prev = int(gps.t_ns[picked[-1]])
        later = np.flatnonzero(usable & (gps.t_ns > t_prev))
        reach = later[gps.t_ns[later] >= t_prev + spacing_ns]
        if reach.size == 0:
            break
        j = int(reach[0])
        before = later[later < j]
        if before.size:
            dt_j, dt_b = int(gps.t_ns[j]) - t_prev, int(gps.t_ns[before[-1]]) - t_prev
            if dt_b >= least_ns and (spacing_ns - dt_b < dt_j - spacing_ns
                                     or dt_j > 2 * spacing_ns):  # fmt: skip
                j = int(before[-1])  # nearer the spacing, or the last before a gap
        picked.append(j)
    complete = len(picked) == n
    idx = np.array(picked if complete else range(min(n, len(gps.t_ns))), int)
    return GpsArrays(gps.t_ns[idx], gps.p_W_G[idx], gps.v_W_G[idx]), complete


def _with_start_velocities(
    gps: GpsArrays, name: str, position_std_m: float, accel_prior_std: float
) -> tuple[GpsArrays, float, float]:
    """``gps`` whose first two fixes carry velocities, the standard deviation (m/s²) of the
    acceleration between them taken from positions and that (m/s per axis) of the first
    velocity so taken (both 0 when the fixes carry velocities).
    From a receiver without velocity, the first three positions differenced: the mean
    velocities over the two intervals, and between them a constant acceleration
    (``v_0 = v_01 - a Δt_01 / 2``, ``v_1 = v_0 + a Δt_01``). A second difference of noisy
    fixes is a poor acceleration, so it is combined with a zero-mean prior of
    ``accel_prior_std`` per axis (the posterior mean and standard deviation)."""
    if np.all(np.isfinite(gps.v_W_G[:2])):
        return gps, 0.0, 0.0
    if len(gps.t_ns) < 3:
        raise InitialisationError(
            f"{name}: --init gps from fixes without velocity needs at least 3 fixes"
        )
    dt01, dt12 = np.diff(gps.t_ns[:3]) * 1e-9
    v01 = (gps.p_W_G[1] - gps.p_W_G[0]) / dt01
    v12 = (gps.p_W_G[2] - gps.p_W_G[1]) / dt12
    # a = (p2/dt12 - p1 (1/dt12 + 1/dt01) + p0/dt01) / mean(dt): independent position noise
    gain = np.sqrt(dt12**-2 + (1 / dt12 + 1 / dt01) ** 2 + dt01**-2)
    var_fix = (position_std_m * gain / (0.5 * (dt01 + dt12))) ** 2
    var_prior = accel_prior_std**2
    a_W = (v12 - v01) / (0.5 * (dt01 + dt12)) * var_prior / (var_prior + var_fix)
    v = gps.v_W_G.copy()
    v[0] = v01 - 0.5 * a_W * dt01
    v[1] = v[0] + a_W * dt01
    accel_std = float(np.sqrt(var_prior * var_fix / (var_prior + var_fix)))
    # v_0: the first difference (√2 σ_p / Δt_01) less half the interval's acceleration
    v0_std = float(np.hypot(np.sqrt(2.0) * position_std_m / dt01, 0.5 * dt01 * accel_std))
    return GpsArrays(gps.t_ns, gps.p_W_G, v), accel_std, v0_std


def _check_start_fixes(gps: GpsArrays, f_W: F64, f_B: F64, v_noise: float, pos_std: float,
                       accel_bias_std: float) -> None:  # fmt: skip
    """Raise ``StartFixesRefusedError`` when the first two fixes (with velocities, noise
    ``v_noise`` m/s and ``pos_std`` m per axis) contradict the IMU or each other; a later pair
    may start the run.

    - The specific force they imply, ``f_W`` (3,) m/s², must have the magnitude the
      accelerometer measured, ``|f_B|``, whatever the attitude (within ``START_FORCE_SIGMAS``
      of the fixes' acceleration noise and the bias prior ``accel_bias_std``): a velocity
      flipped by a glitch gave 4 m/s² on a steady 2 m/s flight, a start 22° tilted and held to
      3° (`3d` 288 m off, a user's probe). Not from position-only fixes: their acceleration is
      shrunk to a prior, and a vehicle braking hard was refused pair after pair (a review).
    - Their positions must be as far apart as their velocities carried the antenna (the
      trapezoid, chi-square at ``START_FIX_PROBABILITY``): a jumped fix placed the start 40 m
      off, and the agreeing fixes after it were refused (a user's probe: 17.3 m).
    """
    ta, tb = int(gps.t_ns[0]), int(gps.t_ns[1])
    dt = (tb - ta) * 1e-9
    moved = 0.5 * (gps.v_W_G[0] + gps.v_W_G[1]) * dt
    d = gps.p_W_G[1] - gps.p_W_G[0] - moved
    d_std = float(np.sqrt(2.0 * pos_std**2 + 0.5 * (dt * v_noise) ** 2))
    if float(d @ d) / d_std**2 > chi2.ppf(START_FIX_PROBABILITY, 3):
        raise StartFixesRefusedError(
            f"the GPS fixes at {ta * 1e-9:.3f} and {tb * 1e-9:.3f} s are "
            f"{np.linalg.norm(gps.p_W_G[1] - gps.p_W_G[0]):.1f} m apart where their velocities "
            f"moved the antenna {np.linalg.norm(moved):.1f} m (± {d_std:.1f} per axis): a fix's "
            "position jumped"
        )  # fmt: skip
    off = abs(float(np.linalg.norm(f_W)) - float(np.linalg.norm(f_B)))
    off_std = float(np.hypot(np.sqrt(2.0) * v_noise / dt, accel_bias_std))
    if off > START_FORCE_SIGMAS * off_std:
        raise StartFixesRefusedError(
            f"the GPS fixes at {ta * 1e-9:.3f} and {tb * 1e-9:.3f} s imply a specific force of "
            f"{np.linalg.norm(f_W):.2f} m/s², the accelerometer measured "
            f"{np.linalg.norm(f_B):.2f} (± {off_std:.2f}): a fix's velocity is wrong"
        )  # fmt: skip


def _from_gps(dataset: InitData, layout: StateLayout, o: InitOptions) -> InitialState:
    """In-flight start (no static interval needed): position and velocity from the first GPS
    fixes; roll and pitch from the mean specific force over the first GPS interval against the
    acceleration the GPS velocities show (``f_B = R^T (a_W - g_W)``; fixes without velocity:
    from the first three positions, ``_with_start_velocities``); heading from the
    magnetometer (TRIAD on that same vector), else from the GPS course at
    ``course_min_speed_mps`` or faster, else, with GPS and vision fused and
    ``heading_from_gps``, a local frame about the antenna (``HEADING_FROM_GPS``: the
    horizontal velocity's direction unknown there, ``VELOCITY_UNKNOWN``), else arbitrary with
    ``yaw_std_unknown``. Biases start at zero with their prior standard deviations."""
    imu, gps = dataset.imu, dataset.gps
    assert imu is not None
    if gps is None or dataset.gps_calib is None or len(gps.t_ns) < 2:
        raise InitialisationError(
            f"{dataset.name}: --init gps needs a GPS stream with at least 2 fixes and its "
            "calibration"
        )
    gps, _ = start_fixes(gps, dataset.gps_calib.velocity_noise_std)
    if np.any(np.diff(gps.t_ns) <= 0):  # (a direct call; the Navigator orders its fixes)
        raise InitialisationError(
            f"{dataset.name}: --init gps needs its first fixes at distinct, increasing times "
            f"(got {', '.join(f'{t * 1e-9:.3f}' for t in gps.t_ns)} s)")
    gps, accel_std, v0_std = _with_start_velocities(gps, dataset.name,
                                            dataset.gps_calib.position_noise_std,
                                            o.flight_accel_prior_std)
    # the start velocity's noise: a calibration's figure may be a velocity fix's, though
    # these velocities were differenced (a data set's fixes cut to positions in memory)
    v_noise = max(dataset.gps_calib.velocity_noise_std, v0_std)
    ta, tb = int(gps.t_ns[0]), int(gps.t_ns[1])
    k = max(2, int(np.searchsorted(imu.t_ns, ta)))
    win = (imu.t_ns >= ta) & (imu.t_ns <= tb)
    if k >= len(imu.t_ns) - 2 or win.sum() < 3:
        raise InitialisationError("fewer than 3 IMU samples between the first two GPS fixes")
    t0 = int(imu.t_ns[k])
    R_B_S = _imu_R_B_S(dataset)
    # The mean specific force over the fixes' interval, each sample turned into the body axes
    # at t0 by the gyro: the GPS's mean acceleration is a world-frame mean, and a rig turning
    # inside the interval smeared the plain body-frame mean (a hand-held rig turning at up to
    # 2.7 rad/s started 20-25° tilted with a σ of 3-6°: a user's probe).
    R_B0_B = gyro_attitudes(np.eye(3), imu.gyro_B[win] @ R_B_S.T, (imu.t_ns[win] - t0) * 1e-9)
    f_B = np.einsum("nij,nj->i", R_B0_B, imu.accel_B[win] @ R_B_S.T) / int(win.sum())
    g_W = np.asarray(dataset.gravity_W, dtype=float)
    a_W = (gps.v_W_G[1] - gps.v_W_G[0]) / ((tb - ta) * 1e-9)
    f_W = a_W - g_W  # the specific force the GPS implies, world frame
    if accel_std == 0.0:  # (position-only fixes' velocities are their positions')
        _check_start_fixes(gps, f_W, f_B, v_noise, dataset.gps_calib.position_noise_std,
                           o.accel_bias_std)  # fmt: skip
    info: dict[str, object] = {"mode": "gps", "gps_acceleration_W": a_W.tolist()}
    yaw_std = o.yaw_std_unknown
    local_velocity = False  # the velocity's horizontal direction unknown (a local frame)
    mag = dataset.mag
    mag_sel = None if mag is None else (mag.t_ns >= ta) & (mag.t_ns <= tb)
    if mag is not None and dataset.mag_calib is not None and mag_sel is not None and mag_sel.any():
        # each field sample in the body axes at t0 too (the IMU sample nearest before it)
        j = np.clip(np.searchsorted(imu.t_ns[win], mag.t_ns[mag_sel], side="right") - 1, 0,
                    int(win.sum()) - 1)  # fmt: skip
        m_S = mag.m_S[mag_sel] @ dataset.mag_calib.T_B_S[:3, :3].T
        m_B = np.einsum("nij,nj->i", R_B0_B[j], m_S) / len(j)
        R_W_B = _triad(f_B, m_B, f_W, np.asarray(dataset.mag_calib.m_W, dtype=float))
        yaw_std = o.yaw_std
        info["heading"] = "magnetometer"
    else:
        R_W_B = _align_up(f_B, f_W / np.linalg.norm(f_W))
        # Attitude from the GPS course while moving (ground vehicle: sideslip ~0), over the
        # same first GPS interval as the specific force.
        course = course_heading_or_none(
            0.5 * (gps.v_W_G[0] + gps.v_W_G[1]), f_B, f_W, imu.gyro_B[win].mean(axis=0) @ R_B_S.T,
            dataset.gps_calib.p_B_G, -g_W, v_noise,
            o.course_min_speed_mps, (0.5 * (ta + tb) - t0) * 1e-9, o.course_max_yaw_std,
        )  # fmt: skip
        gps_fused = getattr(dataset, "gps_fused", None) is not False  # (a Dataset has none)
        if course is not None:
            R_W_B, yaw_std, info["heading"] = course.R_W_B, course.yaw_std_rad, "gps course"
        elif gps_fused and o.heading_from_gps and getattr(dataset, "local_heading_wait", False):
            # A local frame about the antenna, as a static start's, until the GPS gives the
            # heading: the fixes' velocity is the world's, so in that frame only its vertical
            # part and its horizontal speed are known, and vision measures the rest (an
            # arbitrary heading with σ 28.6° was collapsed within a second whatever its error:
            # `3d`, 180° off, 11.0 m, NEES 13778). An unaided INS cannot hold that frame: its
            # velocity's changes alone, tilted by a drifting attitude, gave no heading in 10 s
            # (a simulated 2 m/s flight; a bank of heading hypotheses is the route).
            yaw_std = o.yaw_std_local
            info["heading"] = HEADING_FROM_GPS
            local_velocity = True
            log.warning("no magnetometer and no GPS course at the start (too slow, or too "
                        "uncertain): the heading is taken from the GPS once the motion shows "
                        "it; GPS fixes wait for it")  # fmt: skip
        else:
            info["heading"] = ARBITRARY
            log.warning("no heading source at the start (no magnetometer, no GPS course)")
    x = np.zeros(layout.nx)
    x[Q] = quat_normalize(rotmat_to_quat(R_W_B))
    # Position and velocity of the body at t0 from the first fix (t0 is within one IMU period).
    x[P] = gps.p_W_G[0] + gps.v_W_G[0] * (t0 - ta) * 1e-9 - R_W_B @ dataset.gps_calib.p_B_G
    x[V] = gps.v_W_G[0]
    up_W = -g_W / np.linalg.norm(g_W)
    if local_velocity:
        # its mean over the unknown turn is the vertical part; the horizontal speed's spread
        # over the circle it may point along is |v_h|²/2 per horizontal axis
        v_h = horizontal(gps.v_W_G[0], up_W)
        x[V] = gps.v_W_G[0] - v_h
        info[VELOCITY_UNKNOWN] = round(float(np.linalg.norm(v_h)), 3)
    gyro_B = imu.gyro_B[max(0, k - 2) : k + 1] @ R_B_S.T
    x[W] = gyro_B[-1] if layout.biased else stencil_consistent_rate(gyro_B, len(gyro_B) - 1)
    pos_std = max(o.position_std, 3.0 * dataset.gps_calib.position_noise_std)
    vel_std = max(o.velocity_std, 3.0 * v_noise)
    # Roll/pitch: the mean over a GPS interval hides the attitude changing inside it; an
    # acceleration from differenced positions tilts the specific force by about σ_a / |f|.
    # Velocities differenced add theirs (√2 σ_v / Δt): ``start_fixes`` spaces the fixes for
    # it, a recording whose first fixes are all close together has it here.
    accel_noise = accel_std if accel_std > 0 else np.sqrt(2.0) * v_noise / ((tb - ta) * 1e-9)
    tilt_std = max(o.flight_roll_pitch_std, accel_noise / float(np.linalg.norm(f_W)))
    if accel_std > 0:
        info["gps_acceleration_std"] = accel_std
    P0 = _levelled_covariance(layout, o, R_W_B, up_W, pos_std, vel_std, tilt_std, yaw_std)
    if local_velocity:
        # horizontally the spread over the circle and the fixes' own velocity noise, without
        # the world velocity's threefold margin: position-only fixes differenced give 2 m/s,
        # and 6 m/s per axis let vision's first updates carry the local path 9 m astray in a
        # second (the simulator from 25 s: 3.59 m, NEES 70)
        vertical = np.outer(up_W, up_W)
        spread = 0.5 * float(v_h @ v_h) + v_noise**2
        P0[DV, DV] = vel_std**2 * vertical + spread * (np.eye(3) - vertical)
    return InitialState(t0, x, P0, info)


# m: the start's position when a vision start is followed by GPS fixes (it knows none).
VISION_GPS_POSITION_STD_M = 1000.0


def from_vision_fit(
    fit: VisionInertialFit, t_ns: int, R_W_B: F64, v_W_B: F64, omega_B: F64,
    layout: StateLayout, o: InitOptions, gravity_W: F64, gps_fused: bool,
    m_B: F64 | None = None, m_W: F64 | None = None,
    gps_fix: tuple[F64, float, str] | None = None, p_B_G: F64 | None = None,
) -> InitialState:
    """Initial state at the IMU sample ``t_ns`` from a vision-inertial fit
    (``navigation.vision_start``) carried there: attitude ``R_W_B``, velocity ``v_W_B``, body
    rate ``omega_B`` (gyro minus the fitted bias), position at the origin; the standard
    deviations three times the fit's, floored by the static start's. The heading: from the
    magnetic field ``m_B`` (body frame, mean of the samples at the start) against ``m_W``
    when given (as a static start takes it: TRIAD with the fitted vertical), else a gauge
    (the odometry's first camera's) unless GPS will tie it (and then the position too:
    ``VISION_GPS_POSITION_STD_M``). With GPS fused, ``gps_fix`` (the antenna's position (3,) m
    at ``t_ns``, its standard deviation, m, and how it was had, for the report) and the lever
    arm ``p_B_G`` (3,) m, and no magnetometer: the fix places the body and, with
    ``o.heading_from_gps``, the start defines a local frame until the GPS gives the heading
    (``navigation.heading_wait``; an arbitrary heading with σ ``yaw_std_unknown`` collapsed
    within a second whatever its error: KITTI raw from 18 s, 41° off, ATE 62.8 m, a user's
    probe)."""
    up = -np.asarray(gravity_W, float) / np.linalg.norm(gravity_W)
    heading = ("none (arbitrary yaw: the GPS fixes tie it)" if gps_fused
               else "none (local frame: the start defines its yaw)")  # fmt: skip
    if m_B is not None and m_W is not None:
        R_mag = _triad(R_W_B.T @ up, m_B, up, np.asarray(m_W, float))
        v_W_B = R_mag @ R_W_B.T @ v_W_B
        R_W_B = R_mag
        heading = "magnetometer"
    x = np.zeros(layout.nx)
    x[Q] = quat_normalize(rotmat_to_quat(R_W_B))
    x[V] = v_W_B
    x[W] = omega_B
    if layout.biased:
        x[BG] = fit.b_g
    vel_std = max(o.velocity_std, 3.0 * float(np.max(fit.v_std)))
    tilt_std = max(o.roll_pitch_std, 3.0 * fit.tilt_std)
    # With GPS fused the first fix places the origin-started body (VISION_GPS_POSITION_STD_M),
    # or the fix at the start does.
    pos_std = VISION_GPS_POSITION_STD_M if gps_fused else o.position_std
    if gps_fused and gps_fix is not None:
        lever = np.zeros(3) if p_B_G is None else np.asarray(p_B_G, float)
        x[P] = np.asarray(gps_fix[0], float) - R_W_B @ lever
        pos_std = max(o.position_std, float(gps_fix[1]))
    if heading == "magnetometer":
        yaw_std = o.yaw_std
    elif gps_fused and gps_fix is not None and o.heading_from_gps:
        heading, yaw_std = HEADING_FROM_GPS, o.yaw_std_local
    else:
        yaw_std = o.yaw_std_unknown if gps_fused else o.yaw_std_local
    P0 = _levelled_covariance(layout, o, R_W_B, up, pos_std, vel_std, tilt_std, yaw_std)
    info: dict[str, object] = {
        # the span the frames covered: 4 frames 5 s apart cover 15 s, not init.vision_window_s
        # (a user's probe read 2.0 there)
        "mode": "vision", "heading": heading, "frames": fit.frames, "window_s": fit.span_s,
        "gravity_fit_mps2": fit.g_fit_mps2, "rms_m": fit.rms_m,
        "tilt_std_deg": float(np.degrees(fit.tilt_std)), "velocity_W": v_W_B.tolist(),
        "gyro_bias": fit.b_g.tolist(),
    }
    if gps_fused and gps_fix is not None:
        info["position"] = gps_fix[2]
    return InitialState(int(t_ns), x, P0, info)
