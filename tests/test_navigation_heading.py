"""Heading from the GPS course: lever arm, uncertainty, refusal when too slow, and the in-flight
GPS start without a magnetometer on the real KITTI raw drive."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.errors import InitialisationError
from svains.geometry.rotation import quat_box_minus, quat_to_rotmat, so3_exp
from svains.models.state import BIASED
from svains.navigation.heading import heading_from_course
from svains.navigation.init import initialise
from svains.navigation.options import InitOptions

UP = np.array([0.0, 0.0, 1.0])


def _truth(yaw: float) -> np.ndarray:
    # Slightly rolled and pitched body with heading ``yaw``.
    return so3_exp(np.array([0.0, 0.0, yaw])) @ so3_exp(np.array([0.03, -0.05, 0.0]))


G_W = np.array([0.0, 0.0, -9.81])


@pytest.mark.parametrize("yaw", [0.3, -2.5, 3.1])
def test_course_recovers_attitude_while_turning_with_lever_arm(yaw: float) -> None:
    R = _truth(yaw)
    omega_B = np.array([0.01, -0.02, 0.4])  # turning at 0.4 rad/s
    p_B_G = np.array([-0.5, 0.3, 1.2])
    v_W_B = R @ np.array([8.0, 0.0, 0.0])  # along body x
    v_W_G = v_W_B + R @ np.cross(omega_B, p_B_G)
    a_W = np.cross(R @ omega_B, v_W_B)  # centripetal: the specific force is not vertical
    f_W = a_W - G_W
    f_B = R.T @ f_W
    out = heading_from_course(v_W_G, f_B, f_W, omega_B, p_B_G, UP, 0.05)
    np.testing.assert_allclose(out.R_W_B, R, atol=1e-6)
    # Without the lever-arm correction the antenna's velocity is 0.2 m/s sideways: 25 mrad off.
    no_lever = heading_from_course(v_W_G, f_B, f_W, omega_B, np.zeros(3), UP, 0.05)
    assert np.linalg.norm(quat_box_minus(_rotq(no_lever.R_W_B), _rotq(R))) > 0.01
    assert out.speed_mps == pytest.approx(np.linalg.norm(v_W_B[:2]), rel=1e-6)
    assert out.yaw_std_rad == pytest.approx(np.hypot(0.05 / out.speed_mps, 0.03))


def _rotq(R: np.ndarray) -> np.ndarray:
    from svains.geometry.rotation import rotmat_to_quat

    return rotmat_to_quat(R)


def test_slow_vehicle_is_refused_with_its_speed() -> None:
    with pytest.raises(InitialisationError, match=r"horizontal speed 1\.00 m/s is below 3 m/s"):
        heading_from_course(np.array([1.0, 0.0, 2.0]), -G_W, -G_W, np.zeros(3), np.zeros(3), UP,
                            0.05)


def test_a_course_too_uncertain_is_refused_with_its_uncertainty() -> None:
    """5 m/s with a velocity differenced from 1.4 m fixes (2 m/s per axis): a course ± 23°,
    which a filter cannot carry; a 0.1 m/s velocity at the same speed gives one to ± 2°."""
    v = np.array([5.0, 0.0, 0.0])
    with pytest.raises(InitialisationError, match=r"known to ± 23° only \(at most 10°\)"):
        heading_from_course(v, -G_W, -G_W, np.zeros(3), np.zeros(3), UP, 2.0,
                            max_std_rad=np.radians(10.0))  # fmt: skip
    sure = heading_from_course(v, -G_W, -G_W, np.zeros(3), np.zeros(3), UP, 0.1,
                               max_std_rad=np.radians(10.0))  # fmt: skip
    assert np.degrees(sure.yaw_std_rad) == pytest.approx(np.degrees(np.hypot(0.02, 0.03)))


def test_kitti_gps_start_without_magnetometer_takes_the_course(kitti_raw: Path) -> None:
    from svains.datasets import load_dataset
    from svains.replay.groundtruth import interpolate_groundtruth

    ds = load_dataset(kitti_raw)
    init = initialise(ds, BIASED, InitOptions(mode="gps"))
    assert init.info["heading"] == "gps course"
    _, _, _, q = interpolate_groundtruth(ds.groundtruth, np.array([init.t_ns], np.int64))
    err = quat_box_minus(init.x[6:10], q[0])
    up_B = quat_to_rotmat(init.x[6:10]).T @ UP
    yaw_err = float(err @ up_B)
    yaw_std = float(np.sqrt(up_B @ init.P[6:9, 6:9] @ up_B))
    assert abs(yaw_err) < 3.0 * yaw_std < 0.15, (yaw_err, yaw_std)
    # Roll and pitch too, although the car turns (lateral specific force 1.7 m/s²).
    assert np.degrees(np.linalg.norm(err)) < 3.0
