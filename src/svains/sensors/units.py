"""Unit and frame mistakes a file's syntax cannot show, told from the values: an accelerometer
in g or with gravity removed; a GPS course that turns against the gyro (a mirrored GPS frame) or
by another amount (a gyro in deg/s). Used by the data-set readers (on load) and by the estimator
(online input); pure numpy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# Median accelerometer magnitude over a stream, in units of |gravity|: a vehicle's specific
# force averages about 1 g (a racing quadrotor's median stays under 2 g); outside this band
# the column is in another unit (g, mg, ft/s²) or has gravity removed.
ACCEL_MEDIAN_RANGE_G = (0.5, 3.0)


def accel_units_problem(accel_S: NDArray[np.float64], g_W: NDArray[np.float64]) -> str | None:
    """Why the specific force ``accel_S`` (N, 3) cannot be m/s² with gravity included, given
    gravity ``g_W`` (3,) m/s², or None (also for no samples)."""
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
