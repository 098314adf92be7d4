"""Attitude from the GPS course while moving (in-flight start without a magnetometer).

A ground vehicle moves along its body x axis (sideslip ~0, no lateral or vertical body
velocity), so its velocity gives the direction of body x in the world, as the magnetometer
gives the field's direction. With the specific force (body: the accelerometers; world: the GPS
acceleration minus gravity) the attitude follows by TRIAD: the specific force exactly, body x
in the plane of the two. (Aligning the specific force alone and turning about the vertical
would be wrong whenever the vehicle accelerates or turns: the specific force is then not
vertical.) The GPS measures the antenna's velocity ``v_W_G = v_W_B + R_W_B (ω_B × p_B_G)``;
the lever-arm term depends on the attitude, so it is removed and the attitude recomputed: each
step shrinks the heading error by ``|ω × p_B_G| / v`` (0.03 for a 0.2 m/s lever term at
8 m/s), so four steps leave < 1e-6 rad.

Yaw uncertainty: the GPS velocity noise across the track, ``σ_v / v``, and the sideslip
allowance, added in variance. Below ``min_speed_mps`` the course is unreliable:
``InitialisationError``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import InitialisationError
from svains.geometry.rotation import so3_exp
from svains.navigation.heading_check import horizontal

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CourseHeading:
    """``R_W_B`` (3, 3) from the course, its yaw standard deviation (rad, about the up axis) and
    the horizontal body speed (m/s) it came from."""

    R_W_B: F64
    yaw_std_rad: float
    speed_mps: float


def _frame(a: F64, b: F64) -> F64:
    e1 = a / np.linalg.norm(a)
    e2 = np.cross(a, b)
    e2 /= np.linalg.norm(e2)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


def heading_from_course(
    v_W_G: ArrayLike,
    f_B: ArrayLike,
    f_W: ArrayLike,
    omega_B: ArrayLike,
    p_B_G: ArrayLike,
    up_W: ArrayLike,
    velocity_noise_std: float,
    min_speed_mps: float = 3.0,
    sideslip_std_rad: float = 0.03,
    max_std_rad: float = math.inf,
) -> CourseHeading:
    """``R_W_B`` (3, 3) from the specific force ``f_B`` (3,) / ``f_W`` (3,) m/s² (exact) and body
    x along the body's velocity (from the GPS antenna velocity ``v_W_G`` (3,) m/s, ``omega_B``
    (3,) rad/s and lever arm ``p_B_G`` (3,) m). ``up_W`` (3,) defines the horizontal for the
    speed; ``velocity_noise_std`` m/s per axis. ``InitialisationError`` below
    ``min_speed_mps`` of horizontal speed, or when the heading's standard deviation exceeds
    ``max_std_rad`` (a velocity differenced from position-only fixes, 2 m/s per axis, gave a
    course 38° uncertain at 3 m/s, which the filter could not carry: the simulator from 28 s,
    `3d` 3.67 m, NEES 1081).
    """
    up = np.asarray(up_W, dtype=float)
    up = up / np.linalg.norm(up)
    fB = np.asarray(f_B, dtype=float)
    fW = np.asarray(f_W, dtype=float)
    v_G = np.asarray(v_W_G, dtype=float)
    lever_B = np.cross(np.asarray(omega_B, dtype=float), np.asarray(p_B_G, dtype=float))
    x_B = np.array([1.0, 0.0, 0.0])
    if np.linalg.norm(np.cross(fB, x_B)) < 1e-6 * np.linalg.norm(fB):
        raise InitialisationError("specific force along body x: no attitude from the course")
    v_B = v_G  # the lever-arm term needs the attitude: first without it, then refined
    for _ in range(4):
        speed = float(np.linalg.norm(horizontal(v_B, up)))
        if speed < min_speed_mps:
            raise InitialisationError(
                f"horizontal speed {speed:.2f} m/s is below {min_speed_mps:g} m/s: the GPS course "
                "gives no heading"
            )
        R = _frame(fW, v_B) @ _frame(fB, x_B).T
        v_B = v_G - R @ lever_B
    std = float(np.hypot(velocity_noise_std / speed, sideslip_std_rad))
    if std > max_std_rad:
        raise InitialisationError(
            f"the course at {speed:.2f} m/s with a velocity noise of {velocity_noise_std:.2g} "
            f"m/s is known to ± {math.degrees(std):.0f}° only (at most "
            f"{math.degrees(max_std_rad):.0f}°): the GPS course gives no heading"
        )
    return CourseHeading(R, std, speed)


def course_heading_or_none(
    v_W_G: ArrayLike, f_B: ArrayLike, f_W: ArrayLike, omega_B: ArrayLike, p_B_G: ArrayLike,
    up_W: ArrayLike, velocity_noise_std: float, min_speed_mps: float = 3.0,
    back_s: float = 0.0, max_std_rad: float = math.inf,
) -> CourseHeading | None:
    """:func:`heading_from_course` (inputs averaged over an interval, so the attitude is the
    interval's middle one) turned back by ``back_s`` seconds of the body rate ``omega_B``,
    ``R Exp(-ω back_s)``; None (logged as a warning) when it refuses."""
    try:
        out = heading_from_course(v_W_G, f_B, f_W, omega_B, p_B_G, up_W, velocity_noise_std,
                                  min_speed_mps, max_std_rad=max_std_rad)
    except InitialisationError as exc:
        log.warning("no heading from the GPS course: %s", exc)
        return None
    back = so3_exp(-np.asarray(omega_B, dtype=float) * back_s)
    return CourseHeading(out.R_W_B @ back, out.yaw_std_rad, out.speed_mps)
