"""Unit and frame mistakes a file's syntax cannot show, told from the values: an accelerometer
in g or with gravity removed; a GPS course that turns against the gyro (a mirrored GPS frame) or
by another amount (a gyro in deg/s). Used by the data-set readers (on load) and by the estimator
(online input); pure numpy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

# Median accelerometer magnitude over a stream, in units of |gravity|: a vehicle's specific
# force averages about 1 g (a racing quadrotor's median stays under 2 g); outside this band
# the column is in another unit (g, mg, ft/s²) or has gravity removed.
ACCEL_MEDIAN_RANGE_G = (0.5, 3.0)
# Earth's gravity anywhere on its surface (m/s²): a value outside is a unit or a typing error.
GRAVITY_RANGE_M_S2 = (9.7, 9.9)


def accel_units_problem(accel_S: NDArray[np.float64], g_W: NDArray[np.float64],
                        gyro_S: NDArray[np.float64] | None = None) -> str | None:  # fmt: skip
    """Why the specific force ``accel_S`` (N, 3) cannot be m/s² with gravity included, given
    gravity ``g_W`` (3,) m/s², or None (also for no samples); ``gyro_S`` (N, 3) the same
    samples' rates, to tell columns swapped with the gyro's (None: not judged)."""
    if len(accel_S) == 0:
        return None
    med = float(np.median(np.linalg.norm(accel_S, axis=1)))
    g = float(np.linalg.norm(g_W))
    lo, hi = ACCEL_MEDIAN_RANGE_G
    if lo * g <= med <= hi * g:
        return None
    # Gravity dominates the mean of a specific force: removed, the mean is near zero.
    steady = float(np.linalg.norm(np.mean(accel_S, axis=0))) > 0.5 * med
    guesses = (("g (multiply by 9.81)", 1.0), ("mg", 1000.0), ("ft/s²", g / 0.3048))
    guess = next((name for name, one_g in guesses if abs(med / one_g - 1.0) < 0.2), None)
    if (guess is None or not steady) and gyro_S is not None and len(gyro_S) == len(accel_S):
        med_gyro = float(np.median(np.linalg.norm(gyro_S, axis=1)))
        gyro_steady = float(np.linalg.norm(np.mean(gyro_S, axis=0))) > 0.5 * med_gyro
        if lo * g <= med_gyro <= hi * g and gyro_steady:
            # gravity in the gyro's columns (a header-less CSV with the accelerometer first
            # was told "gravity removed": a user's probe); only where no unit explains the
            # accelerometer (g with a gyro in deg/s turning 15°/s is the unit: a review)
            return (f"the gyro's median magnitude is {med_gyro:.4g} and the accelerometer's "
                    f"{med:.4g}, against gravity {g:.4g} m/s²: are the gyro and accelerometer "
                    "columns swapped? (svains reads t, w_x, w_y, w_z, a_x, a_y, a_z, or the "
                    "columns a header names)")  # fmt: skip
    if guess is None or not steady:
        guess = ("gravity removed (linear acceleration)" if med < lo * g and not steady
                 else "another unit")  # fmt: skip
    return (
        f"the accelerometer's median magnitude is {med:.4g} against gravity {g:.4g} m/s²: it "
        f"looks like {guess}; svains reads specific force in m/s², gravity included (a level "
        "IMU at rest reads +9.8 up)"
    )


# The GPS course against the IMU's turn about the vertical: over steps of at least
# GPS_TURN_STEP_S, moving faster than GPS_TURN_MIN_SPEED_M_S and turning at least
# GPS_TURN_MIN_DEG by the gyro, a cosine below GPS_MIRROR_COSINE over GPS_MIRROR_MIN_STEPS or
# more such steps, GPS_MIRROR_MIN_TURN_DEG in all, says the GPS frame is mirrored. A car's
# course follows its heading (cosine +0.99 on KITTI raw, the simulator's village +0.99); a
# multirotor may fly sideways (+0.5 on the MH_03 trajectory), so only a strong opposite
# agreement counts.
GPS_TURN_STEP_S = 1.0
GPS_TURN_MIN_SPEED_M_S = 2.0
GPS_TURN_MIN_DEG = 3.0
GPS_MIRROR_COSINE = -0.7
GPS_MIRROR_MIN_STEPS = 4
GPS_MIRROR_MIN_TURN_DEG = 45.0
# The same steps, agreeing (cosine above GPS_SCALE_COSINE): the course turns per gyro turn
# (1 for a car: 0.99 on KITTI raw) outside this band says the gyro is in another unit (deg/s:
# 1/57).
GPS_SCALE_COSINE = 0.9
GPS_TURN_RATIO_BAND = (0.2, 5.0)


def course_turn_problem(cosine: float, n: int, turn_deg: float, ratio: float,
                        g_W: NDArray[np.float64]) -> tuple[str, str] | None:  # fmt: skip
    """What the GPS course's turns say against the gyro's: ``cosine`` of the two series of
    per-step turns over ``n`` steps, ``turn_deg`` the gyro's total turn, ``ratio`` the course
    turn per gyro turn; ``g_W`` (3,) m/s² the world's gravity. ``("gyro", why)`` for a gyro in
    another unit, ``("gps", why)`` for a mirrored GPS frame, or None."""
    lo, hi = GPS_TURN_RATIO_BAND
    if cosine > GPS_SCALE_COSINE and n >= GPS_MIRROR_MIN_STEPS and not lo <= ratio <= hi:
        return "gyro", (
            f"the gyro turns {1.0 / ratio:.3g} times as far as the GPS course (cosine "
            f"{cosine:.2f} over {n} turns): "
            + ("is it in deg/s? " if abs(ratio * 180.0 / np.pi - 1.0) < 0.2 else "")
            + "svains reads the gyro in rad/s"
        )
    if (cosine < GPS_MIRROR_COSINE and n >= GPS_MIRROR_MIN_STEPS
            and turn_deg >= GPS_MIRROR_MIN_TURN_DEG):  # fmt: skip
        return "gps", (
            f"the GPS course turns against the IMU (cosine {cosine:.2f} over {n} turns, "
            f"{turn_deg:.0f}° by the gyro): its frame is mirrored against gravity_W "
            f"{np.round(np.asarray(g_W, float), 3).tolist()} (NED, or two axes swapped?); "
            "svains reads a right-handed local frame with gravity_W's up (e.g. ENU)"
        )
    return None


def _vertical_turn(imu_t_ns: NDArray[np.int64], gyro_S: NDArray[np.float64],
                   accel_S: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:  # fmt: skip
    """Times (N,) s from the first sample, the unit up (N, 3) in the IMU's frame (its specific
    force over a 1 s boxcar, by time: irregular streams too) and the gyro's turn about it (N,)
    rad, integrated from the first sample."""
    t = (imu_t_ns - imu_t_ns[0]) * 1e-9
    csum = np.vstack([np.zeros(3), np.cumsum(accel_S, axis=0)])
    lo = np.searchsorted(t, t - 0.5)
    hi = np.searchsorted(t, t + 0.5, side="right")
    up_S = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
    norm = np.linalg.norm(up_S, axis=1)
    up_S = up_S / np.where(norm > 0, norm, np.inf)[:, None]
    rate = np.sum(gyro_S * up_S, axis=1)
    turn = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    return t, up_S, turn


def imu_turn(imu_t_ns: NDArray[np.int64], gyro_S: F64, accel_S: F64) -> tuple[F64, F64]:
    """Times (N,) s from the first sample and the gyro's turn about the vertical (N,) rad
    (``_vertical_turn``): what the GPS course is compared with, computed once for both
    ``gps_course_vs_imu_turn`` and ``gps_clock_shift`` (their ``turn``)."""
    t, _, turn = _vertical_turn(imu_t_ns, gyro_S, accel_S)
    return t, turn


def _course_steps(tg: F64, v_W_G: F64, g_W: F64, lo: float, hi: float,
                  ) -> tuple[NDArray[np.int64], F64, NDArray[np.bool_]] | None:  # fmt: skip
    """The fixes (indices into ``tg`` (M,) s) at least ``GPS_TURN_STEP_S`` apart from ``lo`` to
    ``hi`` s, the course's turn between consecutive ones (rad, about ``g_W``'s up) and whether
    the vehicle moved faster than ``GPS_TURN_MIN_SPEED_M_S`` at both; None with fewer than
    two."""
    steps = np.unique(np.searchsorted(tg, np.arange(lo, hi, GPS_TURN_STEP_S)))
    steps = steps[steps < tg.size]
    if steps.size < 2:
        return None
    up_W = -g_W / np.linalg.norm(g_W)
    e1 = np.cross(up_W, (1.0, 0.0, 0.0) if abs(up_W[0]) < 0.9 else (0.0, 1.0, 0.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up_W, e1)  # (e1, e2, up) right-handed
    v = v_W_G[steps]
    speed = np.hypot(v @ e1, v @ e2)
    d_course = np.angle(np.exp(1j * np.diff(np.arctan2(v @ e2, v @ e1))))
    moving = (speed[1:] > GPS_TURN_MIN_SPEED_M_S) & (speed[:-1] > GPS_TURN_MIN_SPEED_M_S)
    return steps, d_course, moving


def gps_course_vs_imu_turn(
    imu_t_ns: NDArray[np.int64], gyro_S: NDArray[np.float64], accel_S: NDArray[np.float64],
    gps_t_ns: NDArray[np.int64], v_W_G: NDArray[np.float64], g_W: NDArray[np.float64],
    turn: tuple[F64, F64] | None = None,
) -> tuple[float, int, float, float] | None:
    """How the GPS course turns against the IMU's turn about the vertical: (cosine of the two
    series of per-step turns, steps used, total IMU turn in deg, course turn per gyro turn by
    least squares), or None without a usable step. The vertical in the IMU frame is its
    specific force averaged over 1 s, so no mounting calibration is needed (gyro and
    accelerometer share a frame). ``turn``: ``imu_turn``'s, when already computed."""
    if len(imu_t_ns) < 3 or len(gps_t_ns) < 2:
        return None
    t, gyro_turn = turn if turn is not None else imu_turn(imu_t_ns, gyro_S, accel_S)
    tg = (gps_t_ns - imu_t_ns[0]) * 1e-9
    tg_in = tg[(tg >= t[0]) & (tg <= t[-1])]
    if tg_in.size < 2:
        return None
    got = _course_steps(tg, v_W_G, g_W, tg_in[0], tg_in[-1])
    if got is None:
        return None
    steps, d_course, moving = got
    d_turn = np.diff(np.interp(tg[steps], t, gyro_turn))
    ok = moving & (np.abs(d_turn) > np.radians(GPS_TURN_MIN_DEG))
    if not ok.any():
        return None
    a, b = d_course[ok], d_turn[ok]
    cosine = float(a @ b / np.sqrt((a @ a) * (b @ b)))
    return cosine, int(ok.sum()), float(np.degrees(np.sum(np.abs(b)))), float(a @ b / (b @ b))


# The magnetic field in the body frame turns against the body's own turn about the vertical
# (the field stays put, the body turns under it). Over steps of at least MAG_TURN_STEP_S turning
# at least GPS_TURN_MIN_DEG by the gyro, a cosine between the field's turn and the gyro's
# opposite below MAG_MIRROR_COSINE over GPS_MIRROR_MIN_STEPS or more steps and
# GPS_MIRROR_MIN_TURN_DEG in all says the field turns with the body: the magnetometer's axes
# are mirrored against the IMU's through the calibration (an axis reversed, x and y swapped).
MAG_TURN_STEP_S = 1.0
MAG_MIRROR_COSINE = -0.7
MAG_MEAN_S = 0.2  # s of samples averaged at each step's end (the field's direction is noisy)


def mag_turn_vs_gyro(imu_t_ns: NDArray[np.int64], gyro_B: NDArray[np.float64],
                     accel_B: NDArray[np.float64], mag_t_ns: NDArray[np.int64],
                     m_B: NDArray[np.float64]) -> tuple[float, int, float] | None:  # fmt: skip
    """How the magnetic field ``m_B`` (M, 3), in the frame of the IMU's ``gyro_B`` and
    ``accel_B`` (N, 3), turns about the vertical against the gyro: (cosine of the field's
    per-step turns with the gyro's reversed, +1 for a right mount; steps used; total gyro
    turn in deg), or None without a usable step."""
    if len(imu_t_ns) < 3 or len(mag_t_ns) < 2:
        return None
    t, up, turn = _vertical_turn(imu_t_ns, gyro_B, accel_B)
    tm = (np.asarray(mag_t_ns) - imu_t_ns[0]) * 1e-9
    inside = (tm >= t[0]) & (tm <= t[-1])
    if inside.sum() < 2:
        return None
    tm, m = tm[inside], np.asarray(m_B, float)[inside]
    ends = np.arange(tm[0] + MAG_MEAN_S, tm[-1], MAG_TURN_STEP_S)
    if ends.size < 2:
        return None
    csum = np.vstack([np.zeros(3), np.cumsum(m, axis=0)])
    lo = np.searchsorted(tm, ends - MAG_MEAN_S)
    hi = np.searchsorted(tm, ends, side="right")
    ok_mean = hi > lo
    m_end = (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)[:, None]
    k = np.clip(np.searchsorted(t, ends), 0, t.size - 1)
    u = up[k]
    # the field's angle about the vertical, from a body axis projected on the horizontal
    ref = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = ref - np.sum(ref * u, axis=1, keepdims=True) * u
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    angle = np.arctan2(np.sum(m_end * e2, axis=1), np.sum(m_end * e1, axis=1))
    d_field = np.angle(np.exp(1j * np.diff(angle)))
    d_turn = np.diff(np.interp(ends, t, turn))
    ok = (ok_mean[1:] & ok_mean[:-1] & (np.abs(d_turn) > np.radians(GPS_TURN_MIN_DEG))
          & (ref[1:, 0] == ref[:-1, 0]))  # fmt: skip
    if not ok.any():
        return None
    a, b = d_field[ok], -d_turn[ok]
    if not a @ a > 0.0:
        return None  # a field that never turns (a dead or stuck sensor) has no direction
    cosine = float(a @ b / np.sqrt((a @ a) * (b @ b)))
    return cosine, int(ok.sum()), float(np.degrees(np.sum(np.abs(b))))


def mag_turn_problem(cosine: float, n: int, turn_deg: float) -> str | None:
    """Why the field's turns (``mag_turn_vs_gyro``) cannot come from a magnetometer read in
    the IMU's frame, or None."""
    if (cosine < MAG_MIRROR_COSINE and n >= GPS_MIRROR_MIN_STEPS
            and turn_deg >= GPS_MIRROR_MIN_TURN_DEG):  # fmt: skip
        return (
            f"the magnetic field turns with the IMU instead of against it (cosine {cosine:.2f} "
            f"over {n} turns, {turn_deg:.0f}° by the gyro): the magnetometer's axes are "
            "mirrored against the IMU's through its T_BS (an axis reversed, or x and y "
            "swapped?); svains reads the field in the sensor frame that mag0's T_BS maps to "
            "the body"
        )
    return None


# The GPS stamps against the IMU's clock, seconds apart (a receiver stamping GPS time against
# an IMU in UTC: 18 s; a driver's buffer: a second): the course's turns are matched against
# the gyro's over steps of GPS_TURN_STEP_S with the gyro's interval shifted by each shift of
# -GPS_CLOCK_MAX_S … +GPS_CLOCK_MAX_S (GPS_CLOCK_STEP_S apart). Steps where the course turns
# GPS_TURN_MIN_DEG or more while moving count; at least GPS_CLOCK_MIN_STEPS of them. A best
# shift of GPS_CLOCK_MIN_S or more (the online latency search covers less,
# ``navigation.gps_latency``) whose cosine reaches GPS_CLOCK_COSINE while the stamps as given
# fall GPS_CLOCK_MARGIN below it says the clocks differ (KITTI raw as shipped: 0.998 at +0.1 s,
# a car's course lagging its heading, against 0.995 as stamped).
GPS_CLOCK_MAX_S = 30.0
GPS_CLOCK_STEP_S = 0.05
GPS_CLOCK_MIN_S = 0.5
GPS_CLOCK_MIN_STEPS = 6
GPS_CLOCK_COSINE = 0.9
GPS_CLOCK_MARGIN = 0.1
# ... and the shift explains the course that much better than the stamps as given, against
# the misfit left at it: F = (n - 1)(cos² - max(given, 0)²) / (1 - cos²), the least-squares fit's
# improvement over its residual. The best of 1200 shifts over few noisy turns can match by
# chance: a simulated helicopter circling, stamps right, 0.93 at +5.8 s against 0.76 as
# stamped over 6 turns, F 10 (refused: a review); clean flights otherwise F <= 8; stamps
# moved 1-18 s on KITTI raw and on synthetic drives whose course is noisy (σ 0.6 m/s) give
# F 50 and more (a review).
GPS_CLOCK_MIN_F = 25.0


def gps_clock_shift(
    imu_t_ns: NDArray[np.int64], gyro_S: NDArray[np.float64], accel_S: NDArray[np.float64],
    gps_t_ns: NDArray[np.int64], v_W_G: NDArray[np.float64], g_W: NDArray[np.float64],
    turn: tuple[F64, F64] | None = None,
) -> tuple[float, float, float, int] | None:
    """The shift (s, positive: fixes stamped late) that best matches the GPS course's turns to
    the gyro's, its cosine, the cosine of the stamps as given and the steps used; None without
    ``GPS_CLOCK_MIN_STEPS`` turning steps. Like ``gps_course_vs_imu_turn``, no mounting
    calibration is needed; a vehicle that flies sideways (a multirotor) matches at no shift.
    ``turn``: ``imu_turn``'s, when already computed."""
    if len(imu_t_ns) < 3 or len(gps_t_ns) < 2:
        return None
    t, gyro_turn = turn if turn is not None else imu_turn(imu_t_ns, gyro_S, accel_S)
    tg = (gps_t_ns - imu_t_ns[0]) * 1e-9
    got = _course_steps(tg, v_W_G, g_W, tg[0], tg[-1])
    if got is None:
        return None
    steps, d_course, moving = got
    ok = moving & (np.abs(d_course) > np.radians(GPS_TURN_MIN_DEG))
    if ok.sum() < GPS_CLOCK_MIN_STEPS:
        return None
    a = d_course[ok]
    t0, t1 = tg[steps[:-1]][ok], tg[steps[1:]][ok]
    shifts = np.arange(-GPS_CLOCK_MAX_S, GPS_CLOCK_MAX_S + GPS_CLOCK_STEP_S / 2, GPS_CLOCK_STEP_S)
    # A fix stamped tau late held at its stamp minus tau: the gyro's turn over the interval
    # shifted back; intervals outside the IMU's span give no turn (np.interp holds the ends).
    b = (np.interp(t1[None, :] - shifts[:, None], t, gyro_turn)
         - np.interp(t0[None, :] - shifts[:, None], t, gyro_turn))  # fmt: skip
    norm = np.sqrt((a @ a) * np.einsum("ij,ij->i", b, b))
    cosine = np.where(norm > 0, (b @ a) / np.where(norm > 0, norm, 1.0), 0.0)
    k = int(np.argmax(cosine))
    given = float(cosine[int(np.argmin(np.abs(shifts)))])
    return float(shifts[k]), float(cosine[k]), given, int(ok.sum())


def gps_clock_problem(shift_s: float, cosine: float, given: float, n: int) -> str | None:
    """The line to refuse GPS stamps on another clock (``gps_clock_shift``'s figures), or
    None."""
    # (a course turning against the gyro at no shift is explained by nothing there: the
    # course turns with the gyro, its scale positive)
    explained = cosine**2 - max(given, 0.0) ** 2
    gain = (n - 1) * explained / max(1.0 - cosine**2, 1e-12)
    if (abs(shift_s) >= GPS_CLOCK_MIN_S and cosine >= GPS_CLOCK_COSINE
            and given < cosine - GPS_CLOCK_MARGIN and n >= GPS_CLOCK_MIN_STEPS
            and gain >= GPS_CLOCK_MIN_F):  # fmt: skip
        return (
            f"the GPS course turns with the gyro when its stamps are moved {shift_s:+.1f} s "
            f"(cosine {cosine:.2f} over {n} turns; {given:.2f} as stamped): the fixes are "
            f"stamped about {abs(shift_s):.1f} s {'late' if shift_s > 0 else 'early'} against "
            f"the IMU's clock (GPS time against UTC: 18 s); give timeshift_gps_imu: "
            f"{-shift_s:.1f} in gps0/sensor.yaml (the run's latency check finds what remains)"
        )
    return None


# Timestamps are integer nanoseconds: spacings below this (50 kHz) are no sensor's, so the
# stream was stamped in µs, ms or s (``time_unit_problem``; files and the Navigator alike).
MIN_MEDIAN_SPACING_NS = 20_000


def time_unit_problem(median_spacing: float) -> str | None:
    """Why stamps whose median step is ``median_spacing`` (in the stamps' unit) cannot be
    nanoseconds (None when they can)."""
    med = float(median_spacing)
    if not 0 < med < MIN_MEDIAN_SPACING_NS:
        return None
    guess = next((unit for unit, scale in (("microseconds", 1e3), ("milliseconds", 1e6),
                                           ("seconds", 1e9))
                  if 1e-3 <= med * scale * 1e-9 <= 10.0), "another unit")  # fmt: skip
    return (f"timestamps advance by a median {med:g} per sample, {1e9 / med:.3g} Hz if "
            f"nanoseconds: they look like {guess}")



def seconds_unit_hint(t_s: float) -> str:
    """For a stamp read as seconds (a TUM file's) too large for int64 nanoseconds: the unit
    that makes it a time before the year 2286 (1e10 s), as a clause; "" when none does."""
    for name, scale in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)):
        if abs(t_s) / scale < 1e10:
            return (f": a TUM file's stamps are seconds; these look like {name} (divide by "
                    f"{scale:.0e})")
    return ""

# A stream this many times its sensor's declared rate is stamped in another unit than
# nanoseconds, not fast: KITTI's 100 Hz OXTS, kept at a median 40 ms, stamped in microseconds
# reads 25 kHz, inside ``MIN_MEDIAN_SPACING_NS``'s 50 kHz bound.
RATE_UNIT_FACTOR = 100.0
# The fastest stereo camera and GPS receiver a navigation rig carries (Hz): faster streams are
# stamped in another unit (4.84 Hz KITTI frames in microseconds read 4.84 kHz).
MAX_CAMERA_HZ = 500.0
MAX_GPS_HZ = 200.0


def rate_unit_problem(stream_hz: float, limit_hz: float, why: str) -> str | None:
    """Why a stream whose median step, read as nanoseconds, gives ``stream_hz`` cannot be
    stamped in nanoseconds when its sensor gives ``limit_hz`` at most (``why`` says so, e.g.
    "250x sensor.yaml's rate_hz 100"); None when it can. The unit guessed is the first of
    microseconds and milliseconds that brings the stream under the limit."""
    if not (stream_hz > 0 and limit_hz > 0) or stream_hz <= limit_hz:
        return None
    guess = next((f"they look like {unit} ({stream_hz / scale:.3g} Hz then)"
                  for unit, scale in (("microseconds", 1e3), ("milliseconds", 1e6))
                  if stream_hz / scale < limit_hz), "in another unit?")  # fmt: skip
    return f"samples come at {stream_hz:.3g} Hz if the stamps are nanoseconds ({why}): {guess}"


def declared_rate_unit_problem(stream_hz: float, rate_hz: float, whose: str) -> str | None:
    """``rate_unit_problem`` for an IMU whose ``rate_hz`` is declared (``whose``: where, e.g.
    "sensor.yaml's"): ``RATE_UNIT_FACTOR`` times it or more is a unit; None also without a
    declared rate."""
    if not rate_hz > 0:
        return None
    return rate_unit_problem(stream_hz, RATE_UNIT_FACTOR * rate_hz,
                             f"{stream_hz / rate_hz:.3g}x {whose} rate_hz {rate_hz:g}")
