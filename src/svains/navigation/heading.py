"""Heading from the GPS course while moving (in-flight start without a magnetometer).

A ground vehicle moves along its body x axis (sideslip ~0, no lateral or vertical body
velocity), so the horizontal direction of its body velocity is the horizontal direction of its
x axis. The GPS measures the antenna's velocity ``v_W_G = v_W_B + R_W_B (ω_B × p_B_G)``; the
lever-arm term depends on the heading itself, so it is removed with the course heading and the
heading recomputed: each fixed-point step shrinks the heading error by ``|ω × p_B_G| / v``
(0.03 for a 0.2 m/s lever term at 8 m/s), so four steps leave < 1e-6 rad.

Uncertainty: the GPS velocity noise across the track, ``σ_v / v``, and the sideslip allowance,
added in variance. Below ``min_speed_mps`` the course is unreliable: ``InitialisationError``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import InitialisationError
from svains.geometry.rotation import so3_exp

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CourseHeading:
    """``R_W_B`` (3, 3) with the course heading, its yaw standard deviation (rad, about the up
    axis) and the horizontal body speed (m/s) it came from."""

    R_W_B: F64
    yaw_std_rad: float
    speed_mps: float


def _horizontal(v: F64, up: F64) -> F64:
    return v - (v @ up) * up


def heading_from_course(
    v_W_G: ArrayLike,
    R_W_B_levelled: ArrayLike,
    omega_B: ArrayLike,
    p_B_G: ArrayLike,
    up_W: ArrayLike,
    velocity_noise_std: float,
    min_speed_mps: float = 3.0,
    sideslip_std_rad: float = 0.03,
) -> CourseHeading:
    """Turn ``R_W_B_levelled`` (3, 3; roll and pitch right, heading arbitrary) about the up axis
    ``up_W`` (3,) so that the body x axis points along the body's horizontal velocity.

    ``v_W_G`` (3,) m/s GPS antenna velocity; ``omega_B`` (3,) rad/s body rate; ``p_B_G`` (3,) m
    antenna lever arm; ``velocity_noise_std`` m/s per axis. Raises ``InitialisationError`` when
    the horizontal speed is below ``min_speed_mps``.
    """
    up = np.asarray(up_W, dtype=float)
    up = up / np.linalg.norm(up)
    R = np.asarray(R_W_B_levelled, dtype=float)
    v_G = np.asarray(v_W_G, dtype=float)
    lever_B = np.cross(np.asarray(omega_B, dtype=float), np.asarray(p_B_G, dtype=float))
    x_h = _horizontal(R[:, 0], up)
    if np.linalg.norm(x_h) < 1e-6:
        raise InitialisationError("body x axis is vertical: no heading from the course")
    v_B = v_G  # the lever-arm term needs the heading: first without it, then once with it
    for _ in range(4):
        v_h = _horizontal(v_B, up)
        speed = float(np.linalg.norm(v_h))
        if speed < min_speed_mps:
            raise InitialisationError(
                f"horizontal speed {speed:.2f} m/s is below {min_speed_mps:g} m/s: the GPS course "
                "gives no heading"
            )
        # Signed angle about ``up`` from the body x axis to the velocity, both horizontal.
        angle = np.arctan2(np.cross(x_h, v_h) @ up, x_h @ v_h)
        R_out = so3_exp(angle * up) @ R
        v_B = v_G - R_out @ lever_B
    std = float(np.hypot(velocity_noise_std / speed, sideslip_std_rad))
    return CourseHeading(R_out, std, speed)


def course_heading_or_none(
    v_W_G: ArrayLike, R_W_B_levelled: ArrayLike, omega_B: ArrayLike, p_B_G: ArrayLike,
    up_W: ArrayLike, velocity_noise_std: float, min_speed_mps: float = 3.0,
) -> CourseHeading | None:
    """:func:`heading_from_course`, or None (logged as a warning) when it refuses."""
    try:
        return heading_from_course(v_W_G, R_W_B_levelled, omega_B, p_B_G, up_W,
                                   velocity_noise_std, min_speed_mps)
    except InitialisationError as exc:
        log.warning("no heading from the GPS course: %s", exc)
        return None
