"""Load-time checks of calibrations and streams: each error names the file and the field.

A reader calls these right after parsing, so bad values stop the load with a
:class:`CalibrationError` or :class:`DatasetError` instead of surfacing later as a diverged
filter or a silently disabled sensor.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.stereo_sync import match_stereo, nearest_offsets_ns
from svains.datasets.types import (
    CameraCalib,
    Dataset,
    GpsCalib,
    ImageStream,
    ImuCalib,
    MagCalib,
    SonarCalib,
)
from svains.errors import CalibrationError, DatasetError
from svains.sensors.units import (
    GRAVITY_RANGE_M_S2,
    MAX_CAMERA_HZ,
    MAX_GPS_HZ,
    accel_units_problem,
    course_turn_problem,
    declared_rate_unit_problem,
    gps_clock_problem,
    gps_clock_shift,
    gps_course_vs_imu_turn,
    imu_turn,
    mag_turn_problem,
    mag_turn_vs_gyro,
    rate_unit_problem,
)

log = logging.getLogger(__name__)

# Earth's surface gravity spans 9.780 (equator) to 9.832 m/s² (poles), minus 0.003 m/s² per km
# of altitude; the band leaves room for rounding (9.8, 9.81) and local anomalies.
# Largest |R^T R - I| entry of a rotation read from text (Kalibr writes 1e-9; four-decimal
# hand-written matrices 1e-4).
ROTATION_TOL = 1e-3
MIN_BASELINE_M = 1e-3  # any real stereo rig has centimetres
# Lenses sit near the sensor's middle; a principal point outside this fraction of the image
# is more often a calibration in another order than a cropped image (warned, not refused).
PRINCIPAL_POINT_BAND = (0.1, 0.9)
# A principal point this far (relative) towards the origin on both axes by the same factor is
# the intrinsics of a smaller image (refused: runs ended metres off with nothing else said).
PRINCIPAL_POINT_SCALE_OFF = 0.3
# Wide-baseline rigs reach metres; tens of metres is a calibration written in millimetres.
MAX_BASELINE_M = 20.0
# A GPS whose positions cover less than this fraction of the path its velocities integrate to
# while it moves (GPS_MOVING_M_S or faster; at least GPS_MIN_PATH_M of it) has positions in
# another unit (degrees, km). Standing still is left out: there a precise (RTK) position can
# wander less than a noisy velocity integrates to.
GPS_PATH_MIN_RATIO = 0.1
GPS_MOVING_M_S = 0.5
GPS_MIN_PATH_M = 5.0
# Position-only fixes have no velocity to hold them against; their own noise does it: from fix
# to fix a receiver's height moves about as much as its horizontal axes (RTK or not, within a
# few times), while latitude and longitude in degrees move 1e-5 times as much (1 m is 9e-6°).
# A horizontal axis whose median step is below this fraction of the height's (of at least
# GPS_MIN_HEIGHT_STEP_M, so a 2-D fix with a fixed height is left alone) is in another unit;
# one that does not move at all is a receiver holding its position, not a unit.
GPS_POSITION_STEP_RATIO = 1e-3
GPS_MIN_HEIGHT_STEP_M = 1e-3
# Ground-truth quaternions are unit; a norm off by more than this is a broken file.
QUATERNION_NORM_TOL = 1e-2
# A stereo stream whose left frames find a right partner less often than this is warned about.
MIN_PAIRED_FRACTION = 0.5


def check_number(value: float, path: Path, field: str, *, positive: bool = False,
                 non_negative: bool = False) -> None:  # fmt: skip
    """``value`` finite (and > 0 or >= 0 when asked); CalibrationError naming the field."""
    if not math.isfinite(value):
        raise CalibrationError(f"{path}: field '{field}' must be finite, got {value}")
    if positive and not value > 0:
        raise CalibrationError(f"{path}: field '{field}' must be > 0, got {value}")
    if non_negative and value < 0:
        raise CalibrationError(f"{path}: field '{field}' must be >= 0, got {value}")


# A rotation read from text whose |R^T R - I| exceeds ROTATION_EXACT is projected onto the
# nearest rotation, with a warning when that moves it by more than ROTATION_PROJECT_WARN
# (Kalibr's nine digits stay below both: read bit for bit).
ROTATION_EXACT = 1e-9
ROTATION_PROJECT_WARN = 1e-6


def make_orthonormal(T: NDArray[np.float64], path: Path, field: str = "T_BS") -> None:
    """Check the rotation of the 4x4 ``T`` and replace it, in place, by the nearest rotation
    (SVD): ``CalibrationError`` when ``|R^T R - I|`` exceeds ``ROTATION_TOL`` or it is a
    reflection; a warning when the projection moves it by more than ``ROTATION_PROJECT_WARN``.
    A matrix rounded to three decimals (|R^T R - I| 9e-4) was used as it was: EuRoC with
    synthetic features 0.0099 -> 0.0359 m, NEES 56; projected, 0.0105 m (a user's probe)."""
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > ROTATION_TOL:
        raise CalibrationError(
            f"{path}: field '{field}' rotation is not orthonormal (|R^T R - I| = {err:.3g} > "
            f"{ROTATION_TOL:g})"
        )
    if np.linalg.det(R) < 0:
        raise CalibrationError(f"{path}: field '{field}' rotation has det -1 (a reflection)")
    if err <= ROTATION_EXACT:
        return  # a rotation to the file's precision: kept bit for bit
    U, _, Vt = np.linalg.svd(R)
    nearest = U @ Vt
    moved = float(np.max(np.abs(nearest - R)))
    if moved > ROTATION_PROJECT_WARN:
        log.warning("%s: field '%s' rotation is not orthonormal (|R^T R - I| = %.2g, rounded?): "
                    "the nearest rotation is used (entries moved by up to %.2g)", path, field,
                    err, moved)  # fmt: skip
    T[:3, :3] = nearest


def check_rigid(T: NDArray[np.float64], path: Path, field: str = "T_BS") -> None:
    """A rigid transform: finite, last row (0, 0, 0, 1), rotation orthonormal within
    ``ROTATION_TOL`` with det +1, made exactly orthonormal in place (``make_orthonormal``)."""
    if not np.all(np.isfinite(T)):
        raise CalibrationError(f"{path}: field '{field}' has non-finite entries")
    if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0)):
        raise CalibrationError(f"{path}: field '{field}' last row must be 0, 0, 0, 1")
    make_orthonormal(T, path, field)


def check_gravity(g_W: NDArray[np.float64], path: Path, field: str = "gravity_W") -> None:
    """Gravity finite with a plausible magnitude (``GRAVITY_RANGE_M_S2``)."""
    g = float(np.linalg.norm(g_W)) if np.all(np.isfinite(g_W)) else math.nan
    lo, hi = GRAVITY_RANGE_M_S2
    if not lo <= g <= hi:
        raise CalibrationError(
            f"{path}: field '{field}' has magnitude {g:.4g} m/s², expected {lo}-{hi} (Earth)"
        )


def check_imu_calib(c: ImuCalib, path: Path) -> None:
    check_rigid(c.T_B_S, path)
    check_number(c.rate_hz, path, "rate_hz", positive=True)
    check_number(c.gyro_noise_density, path, "gyroscope_noise_density", positive=True)
    check_number(c.accel_noise_density, path, "accelerometer_noise_density", positive=True)
    check_number(c.gyro_random_walk, path, "gyroscope_random_walk", non_negative=True)
    check_number(c.accel_random_walk, path, "accelerometer_random_walk", non_negative=True)
    if c.gyro_range is not None:
        check_number(c.gyro_range, path, "gyroscope_range", positive=True)
    if c.accel_range is not None:
        check_number(c.accel_range, path, "accelerometer_range", positive=True)


# An equidistant (fisheye) model fits a fisheye lens with small coefficients and a rectilinear
# one with k1 near +1/3 (tan θ = θ + θ³/3 + ...); k1 below this, with the last two near zero, is
# a radial-tangential set (k1, k2, p1, p2: EuRoC -0.28 ... 2e-4, KITTI -0.37 ... 1e-3) given
# the wrong model name (KITTI raw: ATE 0.28 -> 1.79 m without a word about the lens)
EQUIDISTANT_K1_MIN = -0.15
TANGENTIAL_SIZE = 0.005


# A camera-IMU time offset beyond this is a unit mistake (milliseconds written as seconds:
# 20 s ran 66 m off, the checks blaming the gyro's unit and the mount: a user's probe).
MAX_TIMESHIFT_S = 1.0


def check_timeshift(value: float, path: Path, field: str = "timeshift_cam_imu") -> None:
    """A camera-IMU offset (s) within ``MAX_TIMESHIFT_S``."""
    check_number(value, path, field)
    if abs(value) > MAX_TIMESHIFT_S:
        raise CalibrationError(
            f"{path}: field '{field}' is {value:g} s, more than {MAX_TIMESHIFT_S:g} s: "
            "milliseconds written as seconds? (it is t_imu - t_cam in seconds)")


def check_camera_calib(c: CameraCalib, path: Path) -> None:
    check_rigid(c.T_B_C, path)
    check_timeshift(c.timeshift_cam_imu_s, path)
    w, h = c.resolution
    if w <= 0 or h <= 0:
        raise CalibrationError(f"{path}: field 'resolution' must be positive, got {w}x{h}")
    # 0: unknown (no rate_hz and fewer than two frames to take it from)
    check_number(c.rate_hz, path, "rate_hz", non_negative=True)
    fu, fv, cu, cv = (float(v) for v in c.intrinsics)
    check_number(fu, path, "intrinsics[0] (fu)", positive=True)
    check_number(fv, path, "intrinsics[1] (fv)", positive=True)
    check_number(cu, path, "intrinsics[2] (cu)")
    check_number(cv, path, "intrinsics[3] (cv)")
    if not np.all(np.isfinite(c.distortion)):
        raise CalibrationError(f"{path}: field 'distortion_coefficients' has non-finite entries")
    k = np.asarray(c.distortion, float)
    if (c.distortion_model == "equidistant" and k.size == 4 and k[0] < EQUIDISTANT_K1_MIN
            and np.all(np.abs(k[2:]) < TANGENTIAL_SIZE)):  # fmt: skip
        log.warning("%s: %s's equidistant (fisheye) coefficients %s look like radial-tangential "
                    "ones (k1 strongly negative, the last two near zero as p1, p2 are): is "
                    "distortion_model right?", path, c.name, np.array2string(k, precision=4))
    lo, hi = PRINCIPAL_POINT_BAND
    if not (lo * w < cu < hi * w and lo * h < cv < hi * h):
        log.warning("%s: the principal point (%.1f, %.1f) px lies near the edge of the %dx%d "
                    "image: intrinsics in another order? (svains reads [fu, fv, cu, cv])",
                    path, cu, cv, w, h)  # fmt: skip
        return
    # Both coordinates towards the origin by the same factor: the intrinsics of the same camera
    # at a lower resolution (a calibration of binned or scaled images).
    su, sv = cu / (0.5 * w), cv / (0.5 * h)
    if max(su, sv) < 1.0 - PRINCIPAL_POINT_SCALE_OFF and abs(su - sv) < 0.1 * max(su, sv):
        s = 0.5 * (su + sv)
        raise CalibrationError(
            f"{path}: the principal point ({cu:.1f}, {cv:.1f}) px sits at {s:.2f} times the "
            f"middle of the {w}x{h} image on both axes: intrinsics of a "
            f"{round(s * w)}x{round(s * h)} image? Scale fu, fv, cu, cv by {1.0 / s:.3g} to "
            f"the images' resolution")


def check_gps_calib(c: GpsCalib, path: Path) -> None:
    if not np.all(np.isfinite(c.p_B_G)):
        raise CalibrationError(f"{path}: field 'T_BS' (lever arm) has non-finite entries")
    check_number(c.position_noise_std, path, "position_noise_std", positive=True)
    check_number(c.velocity_noise_std, path, "velocity_noise_std", positive=True)
    check_number(c.position_correlation_s, path, "position_correlation_s", non_negative=True)


def check_mag_calib(c: MagCalib, path: Path) -> None:
    check_rigid(c.T_B_S, path)
    if not (np.all(np.isfinite(c.m_W)) and np.linalg.norm(c.m_W) > 0):
        raise CalibrationError(f"{path}: field 'reference_field_W' must be finite and non-zero")
    check_number(c.noise_std, path, "noise_std", positive=True)


def check_sonar_calib(c: SonarCalib, path: Path) -> None:
    check_rigid(c.T_B_S, path)
    check_number(c.noise_std, path, "noise_std", positive=True)
    check_number(c.ground_height, path, "ground_height")


def check_rows(t_ns: NDArray[np.int64], path: Path, minimum: int = 1) -> None:
    """A present stream holds at least ``minimum`` samples (a header-only file is an error)."""
    if t_ns.size < minimum:
        raise DatasetError(
            f"{path}: {t_ns.size} data row(s), needs at least {minimum} "
            "(remove the stream folder if the stream is absent)"
        )


def check_quaternions(t_ns: NDArray[np.int64], q_wxyz: NDArray[np.float64], path: Path) -> None:
    """Unit quaternions (norm within ``QUATERNION_NORM_TOL`` of 1), else naming the first row."""
    bad = np.flatnonzero(np.abs(np.linalg.norm(q_wxyz, axis=1) - 1.0) > QUATERNION_NORM_TOL)
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{path}: quaternion at timestamp {t_ns[i]} has norm "
            f"{np.linalg.norm(q_wxyz[i]):.4g}, expected 1 ({bad.size} row(s) affected)"
        )


def check_stereo_rig(cam0: CameraCalib, cam1: CameraCalib, path0: Path, path1: Path) -> None:
    """The right camera sits a baseline away from the left one (``MIN_BASELINE_M``), and both
    have one resolution (the rectification maps one size: a smaller cam1 had every pair
    dropped one by one, the message quoting cam0's size, and the run ended an INS: a user's
    probe)."""
    r0 = tuple(int(v) for v in cam0.resolution)
    r1 = tuple(int(v) for v in cam1.resolution)
    if r0 != r1:
        raise CalibrationError(
            f"{path0}, {path1}: cam0 is {r0[0]}x{r0[1]} px and cam1 {r1[0]}x{r1[1]} px: svains "
            "rectifies a pair of one size; resize one camera's images to the other's (and "
            "scale its intrinsics fu, fv, cu, cv by the same factor)"
        )
    R_B_C0, p_B_C0 = cam0.T_B_C[:3, :3], cam0.T_B_C[:3, 3]
    p_C0_C1 = R_B_C0.T @ (cam1.T_B_C[:3, 3] - p_B_C0)
    b = float(np.linalg.norm(p_C0_C1))
    if b < MIN_BASELINE_M:
        raise CalibrationError(
            f"{path0}, {path1}: 'T_BS' of cam0 and cam1 give a baseline of {b:.3g} m, "
            f"expected > {MIN_BASELINE_M:g} m"
        )
    if b > MAX_BASELINE_M:
        raise CalibrationError(
            f"{path0}, {path1}: 'T_BS' of cam0 and cam1 give a baseline of {b:.4g} m, "
            f"expected < {MAX_BASELINE_M:g} m: translations in millimetres? (svains reads metres)"
        )


def check_accel_units(accel_S: NDArray[np.float64], g_W: NDArray[np.float64], path: Path,
                      gyro_S: NDArray[np.float64] | None = None) -> None:  # fmt: skip
    """DatasetError naming ``path`` when ``accel_S`` (N, 3) is not specific force in m/s²
    (``sensors.units.accel_units_problem``, with the rates ``gyro_S`` (N, 3) when given)."""
    problem = accel_units_problem(accel_S, g_W, gyro_S)
    if problem is not None:
        raise DatasetError(f"{path}: {problem}")


# A stream this much faster than the declared rate cannot come from that sensor: its samples
# would be given less noise than they carry (one sample's variance is σ² times the declared rate)
IMU_RATE_ABOVE_DECLARED = 1.25


def check_imu_rate(t_ns: NDArray[np.int64], rate_hz: float, path: Path) -> None:
    """Warn when the IMU's median sample rate exceeds its declared ``rate_hz`` by more than
    ``IMU_RATE_ABOVE_DECLARED``: each sample's white noise is σ²·rate_hz, so too low a rate
    makes the filter overconfident; refuse it at ``RATE_UNIT_FACTOR`` times (stamps in another
    unit, ``sensors.units.rate_unit_problem``). A stream slower than the declared rate is a
    recording that keeps some of the sensor's samples (KITTI raw's OXTS) and is read as such."""
    u = np.unique(t_ns)
    if u.size < 2 or rate_hz <= 0:
        return
    stream_hz = 1e9 / float(np.median(np.diff(u)))
    unit = declared_rate_unit_problem(stream_hz, rate_hz, "sensor.yaml's")
    if unit is not None:
        raise DatasetError(f"{path}: {unit} (the ASL layout stamps in integer nanoseconds)")
    if stream_hz > IMU_RATE_ABOVE_DECLARED * rate_hz:
        log.warning("%s: samples come at %.4g Hz but sensor.yaml declares rate_hz %.4g: each "
                    "sample is given the noise of a %.4g Hz sensor, %.2gx too little variance; "
                    "set rate_hz to the sensor's own rate", path, stream_hz, rate_hz, rate_hz,
                    stream_hz / rate_hz)  # fmt: skip


# The fastest sensor of each kind whose stamps ``check_stream_unit`` judges (Hz).
STREAM_LIMITS = {"camera pair": MAX_CAMERA_HZ, "GPS receiver": MAX_GPS_HZ}


def check_stream_unit(t_ns: NDArray[np.int64], kind: str, path: Path) -> None:
    """DatasetError naming ``path`` when the frames or fixes stamped ``t_ns`` (N,) of a
    ``kind`` of ``STREAM_LIMITS`` come faster than it gives if read as nanoseconds: stamped
    in another unit (``sensors.units.rate_unit_problem``)."""
    u = np.unique(t_ns)
    if u.size < 3:
        return
    limit_hz = STREAM_LIMITS[kind]
    unit = rate_unit_problem(1e9 / float(np.median(np.diff(u))), limit_hz,
                             f"no {kind} runs above {limit_hz:g} Hz")  # fmt: skip
    if unit is not None:
        raise DatasetError(f"{path}: {unit} (the ASL layout stamps in integer nanoseconds)")


def check_gps_units(t_ns: NDArray[np.int64], p_W_G: NDArray[np.float64],
                    v_W_G: NDArray[np.float64], path: Path) -> None:  # fmt: skip
    """On each axis, GPS positions move as far as their velocities say while moving
    (``GPS_PATH_MIN_RATIO``); positions in degrees or km stand still against them. Per axis,
    since a receiver gives latitude and longitude in degrees but the height in metres. Noise
    only lengthens the position path, so only a path too short is refused."""
    if len(t_ns) < 2:
        return
    dt_s = np.diff(t_ns) * 1e-9
    speed = np.abs(v_W_G)
    mean_speed = 0.5 * (speed[1:] + speed[:-1])  # (N-1, 3)
    moving = mean_speed >= GPS_MOVING_M_S
    v_path = np.sum(np.where(moving, mean_speed * dt_s[:, None], 0.0), axis=0)
    p_path = np.sum(np.where(moving, np.abs(np.diff(p_W_G, axis=0)), 0.0), axis=0)
    bad = np.flatnonzero((v_path >= GPS_MIN_PATH_M) & (p_path < GPS_PATH_MIN_RATIO * v_path))
    if bad.size:
        k = int(bad[0])
        raise DatasetError(
            f"{path}: while moving along axis {'xyz'[k]}, the positions cover {p_path[k]:.3g} m "
            f"and the velocities {v_path[k]:.4g} m: positions in degrees or km? svains reads a "
            "local metric frame (e.g. ENU metres, docs/formats.md)"
        )


# GPS velocities against the positions' own displacement (``gps_velocity_problem``): spans of
# GPS_VEL_SPAN_S over which the positions move at least GPS_VEL_MIN_DISP_M and GPS_VEL_NOISE_K
# times what the fixes' noise could make of it; on most, the velocities' integral misses the
# displacement by more than GPS_VEL_MAX_MISFIT of it. KITTI raw's OXTS misses by 0.6 % (median
# of 3 spans); zeros miss by 100 %, km/h by 260 %, knots by 94 %, another frame by about 140 %.
GPS_VEL_SPAN_S = 10.0
GPS_VEL_MIN_DISP_M = 20.0
GPS_VEL_NOISE_K = 10.0
GPS_VEL_MAX_MISFIT = 0.5


def gps_velocity_problem(
    t_ns: NDArray[np.int64], p_W_G: NDArray[np.float64], v_W_G: NDArray[np.float64],
    position_std: float = 0.0, velocity_std: float = 0.0,
) -> str | None:  # fmt: skip
    """Why the velocities of fixes (N, 3) m/s cannot be the positions' (N, 3) m (None when
    they agree or the positions do not move enough to tell); ``position_std`` (m) and
    ``velocity_std`` (m/s): the fixes' noise per axis."""
    t = (np.asarray(t_ns, np.int64) - int(t_ns[0])) * 1e-9 if len(t_ns) else np.zeros(0)
    if len(t) < 2:
        return None
    step = float(np.median(np.diff(t)))
    # the misfit noise alone makes (3 axes): both end positions, the velocities' integral
    noise_m = math.sqrt(3.0 * (2.0 * position_std**2 + velocity_std**2 * GPS_VEL_SPAN_S * step))
    min_disp = max(GPS_VEL_MIN_DISP_M, GPS_VEL_NOISE_K * noise_m)
    misfits, disps, integrals = [], [], []
    i = 0
    while i < len(t) - 1:
        j = int(np.searchsorted(t, t[i] + GPS_VEL_SPAN_S))
        if j >= len(t):
            break
        disp = p_W_G[j] - p_W_G[i]
        d = float(np.linalg.norm(disp))
        if d >= min_disp:
            v, dt = v_W_G[i : j + 1], np.diff(t[i : j + 1])[:, None]
            integral = np.sum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)  # trapezoids
            misfits.append(float(np.linalg.norm(integral - disp)) / d)
            disps.append(d)
            integrals.append(float(np.linalg.norm(integral)))
        i = j
    if len(misfits) < 2 or float(np.median(misfits)) <= GPS_VEL_MAX_MISFIT:
        return None
    k = int(np.argsort(misfits)[len(misfits) // 2])
    return (f"the velocities integrate to {integrals[k]:.3g} m where the positions move "
            f"{disps[k]:.3g} m over {GPS_VEL_SPAN_S:g} s (median of {len(misfits)} spans: "
            f"{100 * float(np.median(misfits)):.0f} % off): zeros, another unit (km/h, knots) "
            "or another frame than the positions'?")


# Camera stamps jittered around a regular rate (``frame_jitter_problem``): judged only where at
# least JITTER_REGULAR_FRACTION of the spacings lie within JITTER_BAND of their median (a
# camera at a fixed, or slowly changing, rate; keyframes chosen seconds apart are irregular by
# design). Each spacing less its whole number of periods (dropped frames) leaves the stamps'
# own jitter, differenced: differenced again, a rate that changes (30 -> 25 -> 20 Hz) or drifts
# cancels and jitter does not (robust spread / √6); warned above JITTER_WARN_S and
# JITTER_WARN_FRACTION of the period. KITTI raw's camera (207 ms) jitters by 0.12 ms; stamps
# jittered by ±20 ms took `3d` from 0.28 to 1.66 m without a word (a user's probe).
JITTER_REGULAR_FRACTION = 0.5
JITTER_BAND = 0.3
JITTER_WARN_S = 0.002
JITTER_WARN_FRACTION = 0.01


def frame_jitter_problem(t_ns: NDArray[np.int64]) -> str | None:
    """Why the frame stamps ``t_ns`` (N,) look jittered (None: regular, or irregular by
    design, or too few)."""
    dt = np.diff(np.unique(np.asarray(t_ns, np.int64))) * 1e-9
    if dt.size < 20:
        return None
    period = float(np.median(dt))
    if period <= 0 or np.mean(np.abs(dt - period) <= JITTER_BAND * period) < (
            JITTER_REGULAR_FRACTION):  # fmt: skip
        return None
    residual = dt - np.maximum(1.0, np.round(dt / period)) * period
    d = np.diff(residual)
    jitter = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(6.0)
    if jitter <= max(JITTER_WARN_S, JITTER_WARN_FRACTION * period):
        return None
    return (f"the frame stamps scatter by about {jitter * 1e3:.1f} ms (robust std) around a "
            f"{period * 1e3:.1f} ms period: stamps taken on arrival (software) rather than at "
            "exposure? The estimator takes them as exact; stamp at exposure (or trigger), or "
            "smooth them onto the camera's rate")


# An IMU clipped at its full scale with no range in its sensor.yaml (``clipping_range``): an axis
# whose largest magnitude is held for CLIP_MIN_RUN samples in a row, CLIP_MIN_SAMPLES in all (a
# noisy reading never repeats its extreme; EuRoC V1_01 and KITTI raw: no axis does). The range
# found is given to the IMU guard, which drops the clipped samples (a user's probe: a gyro
# clipped at 0.5 rad/s, undeclared, took `3d` 23.9 m off on EuRoC; declared, 1.87 m).
CLIP_MIN_RUN = 3
CLIP_MIN_SAMPLES = 10


def clipping_range(values: NDArray[np.float64]) -> float | None:
    """The full scale (N, 3) readings seem clipped at (the largest magnitude, held), or None."""
    v = np.abs(np.asarray(values, dtype=float))
    if v.shape[0] < CLIP_MIN_SAMPLES or not np.isfinite(v).all():
        return None
    top = float(v.max())
    if top <= 0.0:
        return None
    at_top = v == top
    if int(at_top.sum()) < CLIP_MIN_SAMPLES:
        return None
    for axis in range(v.shape[1]):
        top_run = _longest_run(at_top[:, axis])
        # a quantised reading repeats values anywhere (a turn's flat peak too): the top must be
        # held longer than any other value is (a user's probe: a 16-bit gyro's peak rate,
        # repeated for a few samples, read as a full scale)
        x = np.asarray(values, dtype=float)[:, axis]
        same = np.concatenate([[False], x[1:] == x[:-1]]) & ~at_top[:, axis]
        if top_run >= CLIP_MIN_RUN and top_run > 2 * (_longest_run(same) + 1):
            return top
    return None


def _longest_run(flags: NDArray[np.bool_]) -> int:
    """The longest run of True in ``flags`` (N,)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(np.int8), [0]])))
    return int(np.max(edges[1::2] - edges[::2])) if edges.size else 0


def check_gps_position_units(p_W_G: NDArray[np.float64], path: Path) -> None:
    """Position-only fixes ``p_W_G`` (N, 3): a horizontal axis whose median step from fix to
    fix is below ``GPS_POSITION_STEP_RATIO`` times the height's (``GPS_MIN_HEIGHT_STEP_M`` or
    more), yet not zero, is latitude or longitude in degrees (or km): refused, naming it."""
    p = np.asarray(p_W_G, dtype=float)
    if p.shape[0] < 3:
        return
    step = np.median(np.abs(np.diff(p, axis=0)), axis=0)
    if not step[2] >= GPS_MIN_HEIGHT_STEP_M:
        return
    bad = np.flatnonzero((step[:2] > 0.0) & (step[:2] < GPS_POSITION_STEP_RATIO * step[2]))
    if bad.size:
        k = int(bad[0])
        raise DatasetError(
            f"{path}: from fix to fix axis {'xyz'[k]} moves {step[k]:.3g} m (median) where the "
            f"height moves {step[2]:.3g} m: positions in degrees or km? svains reads a local "
            "metric frame (e.g. ENU metres, docs/formats.md)"
        )


# The GPS course against the gyro (``check_gps_against_gyro``): thresholds and verdict in
# ``svains.sensors.units`` (the estimator checks online input the same way).


def check_gps_against_gyro(ds: Dataset, path: Path, imu_path: Path) -> None:
    """DatasetError when the GPS course turns against the IMU (``gps_course_vs_imu_turn``):
    a GPS in a mirrored frame (NED or a swapped axis against ``gravity_W``'s z-up); or with it
    but by another amount: a gyro in deg/s."""
    if ds.imu is None or ds.gps is None:
        return
    g_W = np.asarray(ds.gravity_W, float)
    streams = (ds.imu.t_ns, ds.imu.gyro_B, ds.imu.accel_B, ds.gps.t_ns,
               ds.gps.velocity_or_differenced(), g_W)  # fmt: skip
    turn = imu_turn(*streams[:3]) if len(ds.imu.t_ns) >= 3 else None
    got = gps_course_vs_imu_turn(*streams, turn=turn)
    if got is None:
        return
    problem = course_turn_problem(*got, g_W)
    if problem is not None:
        kind, why = problem
        raise DatasetError(f"{imu_path if kind == 'gyro' else path}: {why}")
    shift = gps_clock_shift(*streams, turn=turn)
    clock = None if shift is None else gps_clock_problem(*shift)
    if clock is not None:
        raise DatasetError(f"{path}: {clock}")


def mag_frame_turn(ds: Dataset) -> tuple[float, int, float] | None:
    """``mag_turn_vs_gyro`` on ``ds``'s magnetometer and IMU, both taken to the body frame
    through their ``T_BS`` (None without both, their calibrations or a usable turn)."""
    if ds.imu is None or ds.mag is None or ds.imu_calib is None or ds.mag_calib is None:
        return None
    R_imu, R_mag = ds.imu_calib.T_B_S[:3, :3], ds.mag_calib.T_B_S[:3, :3]
    return mag_turn_vs_gyro(ds.imu.t_ns, ds.imu.gyro_B @ R_imu.T, ds.imu.accel_B @ R_imu.T,
                            ds.mag.t_ns, ds.mag.m_S @ R_mag.T)  # fmt: skip


def check_mag_against_gyro(ds: Dataset, path: Path) -> None:
    """DatasetError when the magnetic field turns with the body instead of against it
    (``mag_turn_vs_gyro``): the magnetometer's axes mirrored against the IMU's through the
    calibrations (an axis reversed; x and y swapped, as the MPU-9250's AK8963 against its
    accelerometer)."""
    got = mag_frame_turn(ds)
    problem = None if got is None else mag_turn_problem(*got)
    if problem is not None:
        raise DatasetError(f"{path}: {problem}")


def _find_clipping(ds: Dataset, path: Path) -> None:
    """Warn of, and declare to the guard (``ds.imu_calib``), a full scale the IMU's readings
    show but its calibration does not give."""
    assert ds.imu is not None and ds.imu_calib is not None
    found = {}
    for name, values, declared in (("gyroscope", ds.imu.gyro_B, ds.imu_calib.gyro_range),
                                   ("accelerometer", ds.imu.accel_B, ds.imu_calib.accel_range)):
        top = None if declared is not None else clipping_range(values)
        if top is not None:
            found[name] = top
            unit = "rad/s" if name == "gyroscope" else "m/s²"
            log.warning("%s: the %s's readings are held at ±%.4g %s (runs of %d or more "
                        "samples): clipped at its full scale? Taken as its range, the clipped "
                        "samples dropped; give %s_range in sensor.yaml", path, name, top, unit,
                        CLIP_MIN_RUN, name)  # fmt: skip
    if found:
        c = ds.imu_calib
        ds.imu_calib = replace(c, gyro_range=found.get("gyroscope", c.gyro_range),
                               accel_range=found.get("accelerometer", c.accel_range))  # fmt: skip


# The ground truth's attitudes put the IMU's mean specific force this far (deg) from up
# (-gravity_W) or more: gravity_W or the reference in another frame (warned).
GRAVITY_REFERENCE_WARN_DEG = 30.0


def gravity_reference_problem(ds: Dataset, samples: int = 4000) -> str | None:
    """Whether the IMU's specific force, turned into the world by the ground truth's attitude
    at each sample and averaged over the run (the run's mean acceleration is small against
    gravity), points against ``gravity_W`` as it must; a sentence naming the angle when it is
    ``GRAVITY_REFERENCE_WARN_DEG`` or more off, else None. ``gravity_W`` [0, 0, +9.81] (a
    z-down world) was accepted with only its size checked: 50 m off from a ground-truth start,
    a static one upside down against the reference (a user's probe)."""
    from svains.geometry.rotation import quat_to_rotmat

    gt, imu = ds.groundtruth, ds.imu
    if gt is None or imu is None or len(gt.t_ns) < 2 or len(imu.t_ns) < 2:
        return None
    inside = (imu.t_ns >= gt.t_ns[0]) & (imu.t_ns <= gt.t_ns[-1])
    idx = np.flatnonzero(inside)
    if idx.size < 100:
        return None
    idx = idx[np.linspace(0, idx.size - 1, min(samples, idx.size)).astype(int)]
    j = np.clip(np.searchsorted(gt.t_ns, imu.t_ns[idx]), 0, len(gt.t_ns) - 1)
    R = quat_to_rotmat(gt.q_W_B_wxyz[j])
    f_W = np.einsum("nij,nj->i", R, imu.accel_B[idx]) / idx.size
    up = -np.asarray(ds.gravity_W, float)
    cos = float(f_W @ up) / max(float(np.linalg.norm(f_W) * np.linalg.norm(up)), 1e-12)
    angle = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
    if angle < GRAVITY_REFERENCE_WARN_DEG:
        return None
    up_txt = (np.round(up, 3) + 0.0).tolist()  # + 0.0: no "-0.0"
    return (f"the ground truth's attitudes turn the IMU's mean specific force "
            f"{angle:.0f}° from up (-gravity_W {up_txt}): gravity_W with the wrong sign (a "
            "z-down world? svains's world has z up, gravity [0, 0, -9.81]), a reference in "
            "another frame, or an IMU in other axes than imu0's T_BS says (forward-right-down "
            "axes given as the identity?)")


def vet_streams(ds: Dataset) -> None:
    """The units, clocks and frames a reader cannot see in a file's syntax, for every format:
    the IMU's specific force (``check_accel_units``), GPS positions against its velocities
    (``check_gps_units``; position-only fixes: their horizontal steps against their height's,
    ``check_gps_position_units``), every stream's span against the IMU's (a sensor stream that never
    meets it is refused; a reference that never does is dropped from ``ds`` with a warning),
    the GPS course against the gyro (``check_gps_against_gyro``) and the magnetic field's turns
    against the gyro's (``check_mag_against_gyro``). The error names the
    stream's ASL file where there is one."""

    def where(folder: str) -> Path:
        csv = ds.root / "mav0" / folder / "data.csv"
        return csv if csv.is_file() else ds.root / folder

    if ds.imu is not None:
        check_accel_units(ds.imu.accel_B, ds.gravity_W, where("imu0"), ds.imu.gyro_B)
        upside = gravity_reference_problem(ds)
        if upside is not None:
            log.warning("%s: %s", ds.root / "mav0" / "body.yaml", upside)
        if ds.imu_calib is not None:
            check_imu_rate(ds.imu.t_ns, ds.imu_calib.rate_hz, where("imu0"))
            _find_clipping(ds, where("imu0"))
    if ds.gps is not None and ds.gps.has_velocity.all():
        check_gps_units(ds.gps.t_ns, ds.gps.p_W_G, ds.gps.v_W_G, where("gps0"))
        c = ds.gps_calib
        why = gps_velocity_problem(ds.gps.t_ns, ds.gps.p_W_G, ds.gps.v_W_G,
                                   0.0 if c is None else c.position_noise_std,
                                   0.0 if c is None else c.velocity_noise_std)  # fmt: skip
        if why is not None:
            # The positions are sound (the check above): the run goes on with them alone, as
            # for a position-only receiver (a user's probe: zero velocities fused, `ins` 152 m).
            log.warning("%s: %s; the velocities are left out, the positions used",
                        where("gps0"), why)  # fmt: skip
            ds.gps = replace(ds.gps, v_W_G=np.full_like(ds.gps.v_W_G, np.nan))
    elif ds.gps is not None:  # position-only: the fixes' own steps, per axis
        check_gps_position_units(ds.gps.p_W_G, where("gps0"))
    for folder, stamped, kind in (("cam0", ds.left, "camera pair"),
                                  ("cam1", ds.right, "camera pair"),
                                  ("gps0", ds.gps, "GPS receiver")):  # fmt: skip
        if stamped is not None:
            check_stream_unit(stamped.t_ns, kind, where(folder))
    if ds.left is not None and len(ds.left.t_ns):  # (features0 is read when first used)
        jitter = frame_jitter_problem(ds.left.t_ns)
        if jitter is not None:
            log.warning("%s: %s", where("cam0"), jitter)
    if ds.imu is None or len(ds.imu.t_ns) == 0:
        return
    t0, t1 = int(ds.imu.t_ns[0]), int(ds.imu.t_ns[-1])
    streams = (("cam0", ds.left, "timeshift_cam_imu in cam0/sensor.yaml"),
               ("cam1", ds.right, "timeshift_cam_imu in cam1/sensor.yaml"),
               ("gps0", ds.gps, "timeshift_gps_imu in gps0/sensor.yaml"),
               ("mag0", ds.mag, None), ("sonar0", ds.sonar, None),
               ("state_groundtruth_estimate0", ds.groundtruth, None))  # fmt: skip
    for folder, stream, key in streams:
        if stream is None or len(stream.t_ns) == 0:
            continue
        s0, s1 = int(stream.t_ns[0]), int(stream.t_ns[-1])
        if s1 >= t0 and s0 <= t1:
            continue
        off = (s0 - t0) * 1e-9
        msg = (f"{where(folder)}: its stamps ({s0 * 1e-9:.3f}-{s1 * 1e-9:.3f} s) lie "
               f"{abs(off):.3f} s {'after' if off > 0 else 'before'} the IMU's "
               f"({t0 * 1e-9:.3f}-{t1 * 1e-9:.3f} s) and never meet them: another clock? "
               "Every stream is stamped on the IMU's clock (integer ns)"
               + (f"; a known offset goes in {key}" if key else ""))  # fmt: skip
        if folder.startswith("state_"):
            # the reference only scores a run: it is left out, not the run refused
            log.warning("%s; the reference is not used", msg)
            ds.groundtruth = None
            continue
        raise DatasetError(msg)
    check_gps_against_gyro(ds, where("gps0"), where("imu0"))
    check_mag_against_gyro(ds, where("mag0"))


def png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG header without decoding; None for other content."""
    with path.open("rb") as fh:
        head = fh.read(24)
    if head[:8] == _PNG_SIGNATURE and len(head) == 24:
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    return None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# How far from a file's end its closing chunk (PNG ``IEND``, JPEG ``FFD9``) is looked for: some
# writers pad a few bytes after it.
_END_WINDOW = 64


def image_file_problem(path: Path) -> str | None:
    """Why the image at ``path`` cannot be decoded, read from its first and last bytes only
    (a PNG or JPEG cut short has no closing chunk; an empty file, or a ``.png`` that is not one);
    None when it looks whole or its format is not one of those two."""
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            head = fh.read(8)
            fh.seek(max(0, size - _END_WINDOW))
            tail = fh.read()
    except OSError as e:
        return f"cannot be read ({e.strerror})"
    if size == 0:
        return "empty file"
    if head == _PNG_SIGNATURE:
        return None if b"IEND" in tail else "no PNG end chunk (cut short?)"
    if head[:2] == b"\xff\xd8":
        return None if b"\xff\xd9" in tail else "no JPEG end marker (cut short?)"
    if path.suffix.lower() == ".png":
        return "not a PNG (no PNG signature)"
    return None


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image: from the PNG header, else by decoding it."""
    size = png_size(path)
    if size is not None:
        return size
    from svains.datasets._image_io import read_grey

    img = read_grey(path)
    return int(img.shape[1]), int(img.shape[0])


def check_image_size(stream: ImageStream, calib: CameraCalib, yaml_path: Path,
                     decode: bool = False) -> None:  # fmt: skip
    """The first image has the calibration's ``resolution`` (a PNG header read; other formats
    are checked when decoded, or here with ``decode``: a bag's images, a calibration given
    apart from the recording)."""
    if len(stream) == 0:
        return
    first = stream.paths[0]
    size = png_size(first) if first.is_file() else None
    if size is None and decode:
        try:
            img = stream.load(0)
        except DatasetError:
            return  # an unreadable first image: the run drops it with a warning
        size = (int(img.shape[1]), int(img.shape[0]))
    if size is not None and size != tuple(calib.resolution):
        raise CalibrationError(
            f"{stream.paths[0]}: image is {size[0]}x{size[1]} px but {yaml_path} field "
            f"'resolution' says {calib.resolution[0]}x{calib.resolution[1]}"
        )


# Recorded features: observations before a verdict, the share at negative disparity that means
# the columns are crossed, the median row offset (px, at least 3 pixel noises) that means the
# pixels are not in a rectified pair (the values of ``frontend.stereo_check`` for images).
FEATURES_MIN_OBSERVATIONS = 60
FEATURES_SWAPPED_FRACTION = 0.8
FEATURES_ROW_OFFSET_PX = 3.0


def check_feature_disparity(uv_left: NDArray[np.float64], uv_right: NDArray[np.float64],
                            pixel_noise_std: float, path: Path) -> None:  # fmt: skip
    """Recorded stereo features (M, 2) px in the rectified pair: ``DatasetError`` when most
    observations (of ``|u_left - u_right| >= 1`` px) lie at negative disparity (the right pixel
    right of the left one: the left and right columns crossed, or cam0 and cam1), a warning
    when left and right pixels are rows apart (not a rectified pair: a median row offset above
    ``FEATURES_ROW_OFFSET_PX`` and 3 times the pixel noise ``pixel_noise_std`` px)."""
    with np.errstate(over="ignore"):  # pixels near ±1e308 differ by ±inf: its sign holds
        d = uv_left[:, 0] - uv_right[:, 0]
    seen = np.abs(d) >= 1.0
    n = int(seen.sum())
    if n < FEATURES_MIN_OBSERVATIONS:
        return
    negative = int((d[seen] < 0).sum())
    if negative >= FEATURES_SWAPPED_FRACTION * n:
        raise DatasetError(
            f"{path}: {negative} of {n} observations lie at negative disparity (u_right right of "
            "u_left): are the left and right columns swapped? Rows are track_id, u_left, "
            "v_left, u_right, v_right")  # fmt: skip
    with np.errstate(over="ignore", invalid="ignore"):
        rows = float(np.median(np.abs(uv_left[seen, 1] - uv_right[seen, 1])))
    if rows > max(FEATURES_ROW_OFFSET_PX, 3.0 * pixel_noise_std):
        log.warning("%s: left and right pixels are %.1f px apart in rows (median of %d): "
                    "features0 is read as a rectified pair, where they share a row", path,
                    rows, n)  # fmt: skip


def check_stereo_sync(left: ImageStream, right: ImageStream, tol_ns: int, where: str) -> None:
    """Left frames find right partners within ``tol_ns``: none is an error, few a warning."""
    if len(left) == 0 or len(right) == 0:
        return
    idx_l, _ = match_stereo(left.t_ns, right.t_ns, tol_ns)
    if idx_l.size == 0:
        off = float(np.median(nearest_offsets_ns(left.t_ns, right.t_ns))) * 1e-6
        raise DatasetError(
            f"{where}: no left frame has a right frame within {tol_ns * 1e-6:g} ms (median "
            f"offset {off:.3g} ms); set stereo_pair_tolerance_ns in body.yaml if the pairs are "
            "that far apart"
        )
    if idx_l.size < MIN_PAIRED_FRACTION * len(left):
        log.warning(
            "%s: only %d of %d left frames have a right frame within %g ms",
            where, idx_l.size, len(left), tol_ns * 1e-6,
        )  # fmt: skip
