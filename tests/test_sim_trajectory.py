"""Simulator trajectories: exact derivatives (strapdown), village geometry, TUM following."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import TRAJECTORIES
from svains.errors import ConfigError, DatasetError
from svains.geometry.rotation import quat_to_rotmat, skew, so3_log
from svains.sim.trajectory import (
    SplineTrajectory,
    read_tum,
    rounded_rectangle,
    tum_trajectory,
    village_trajectory,
)

G_W = np.array([0.0, 0.0, -9.81])


def _catmull_rom(y: np.ndarray, k: int, s: float) -> np.ndarray:
    """Sample-only interpolation at k + s from samples k-1..k+2 (clamped at the ends)."""
    n = len(y)
    p0, p1, p2, p3 = y[[max(k - 1, 0), k, min(k + 1, n - 1), min(k + 2, n - 1)]]
    return 0.5 * (2 * p1 + (p2 - p0) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s**2
                  + (3 * p1 - p0 - 3 * p2 + p3) * s**3)  # fmt: skip


def strapdown(t0: float, gyro: np.ndarray, accel: np.ndarray, dt: float, R0, v0, p0):
    """Plain RK4 strapdown integration of IMU samples (gyro, specific force) in W (z up)."""
    R, v, p = R0.copy(), v0.copy(), p0.copy()

    def deriv(R, k, s):
        return R @ skew(_catmull_rom(gyro, k, s)), R @ _catmull_rom(accel, k, s) + G_W

    for k in range(len(gyro) - 1):
        dR1, dv1 = deriv(R, k, 0.0)
        v2 = v + 0.5 * dt * dv1
        dR2, dv2 = deriv(R + 0.5 * dt * dR1, k, 0.5)
        v3 = v + 0.5 * dt * dv2
        dR3, dv3 = deriv(R + 0.5 * dt * dR2, k, 0.5)
        v4 = v + dt * dv3
        dR4, dv4 = deriv(R + dt * dR3, k, 1.0)
        p = p + dt / 6 * (v + 2 * v2 + 2 * v3 + v4)
        v = v + dt / 6 * (dv1 + 2 * dv2 + 2 * dv3 + dv4)
        R = R + dt / 6 * (dR1 + 2 * dR2 + 2 * dR3 + dR4)
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
    return R, v, p


def _check_strapdown(traj: SplineTrajectory, t0: float, t1: float) -> tuple[float, float]:
    t = np.arange(round(t0 * 100), round(t1 * 100) + 1) / 100.0
    s = traj.evaluate(t)
    R, _, p = strapdown(t0, s.omega_B, s.specific_force_B(G_W), 0.01, s.R_W_B[0], s.v_W_B[0],
                        s.p_W_B[0])
    return float(np.linalg.norm(p - s.p_W_B[-1])), float(np.linalg.norm(so3_log(R.T @ s.R_W_B[-1])))


def test_village_strapdown_reproduces_truth_over_10s_with_a_corner() -> None:
    traj = village_trajectory(25.0, (60.0, 45.0), 5.0, 2.0, 2.0, seed=1)
    # 10 s window containing the first corner (straight half-side is 12.5 m = 6.25 s)
    pos_err, att_err = _check_strapdown(traj, 8.0, 18.0)
    assert pos_err < 0.01
    assert att_err < 1e-4


@pytest.mark.realdata  # a trajectory of ../shared/data/trajectories
def test_tum_strapdown_reproduces_truth(tmp_path) -> None:
    traj = tum_trajectory(TRAJECTORIES / "euroc_V1_02_medium_groundtruth.tum", 25.0)
    pos_err, att_err = _check_strapdown(traj, 10.0, 20.0)
    assert pos_err < 0.01
    assert att_err < 1e-4


def test_body_rate_and_acceleration_are_derivatives() -> None:
    traj = village_trajectory(20.0, (60.0, 45.0), 5.0, 2.0, 2.0)
    t = np.linspace(1.0, 19.0, 37)
    h = 1e-5
    s, sp, sm = traj.evaluate(t), traj.evaluate(t + h), traj.evaluate(t - h)
    omega_fd = so3_log(np.einsum("nji,njk->nik", sm.R_W_B, sp.R_W_B)) / (2 * h)
    np.testing.assert_allclose(s.omega_B, omega_fd, atol=1e-6)
    np.testing.assert_allclose(s.alpha_B, (sp.omega_B - sm.omega_B) / (2 * h), atol=1e-4)
    np.testing.assert_allclose(s.v_W_B, (sp.p_W_B - sm.p_W_B) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(s.a_W, (sp.v_W_B - sm.v_W_B) / (2 * h), atol=1e-4)


def test_village_flies_the_paper_rectangle() -> None:
    traj = village_trajectory(110.0, (60.0, 45.0), 5.0, 2.0, 2.0)
    s = traj.evaluate(np.arange(0.0, 110.0, 0.1))
    speed = np.linalg.norm(s.v_W_B, axis=1)
    assert np.all(np.abs(speed - 2.0) < 0.05)
    np.testing.assert_allclose(s.p_W_B[:, 2], 2.0, atol=1e-9)
    assert s.p_W_B[:, 0].max() > 29.0 and s.p_W_B[:, 1].max() > 21.5
    # continuous acceleration: no jump between consecutive 10 ms samples
    fine = traj.evaluate(np.arange(0.0, 110.0, 0.01))
    assert np.abs(np.diff(fine.a_W, axis=0)).max() < 0.05
    # counter-clockwise turns bank left: the body's up axis leans towards +y of the heading
    f_B = fine.specific_force_B(G_W)
    assert np.abs(f_B[:, 1]).max() < 0.5  # coordinated turn: small lateral specific force
    turning = fine.omega_B[:, 2] > 0.2
    tilt_left = np.einsum("nij,j->ni", fine.R_W_B, [0.0, 0.0, 1.0])
    heading = fine.v_W_B / np.linalg.norm(fine.v_W_B, axis=1, keepdims=True)
    left = np.cross([0.0, 0.0, 1.0], heading)
    assert np.all(np.einsum("ni,ni->n", tilt_left[turning], left[turning]) > 0.02)


def test_rounded_rectangle_is_closed_and_continuous() -> None:
    size, r = (60.0, 45.0), 5.0
    perim = 2 * (60 + 45) - 8 * r + 2 * np.pi * r
    s = np.linspace(0.0, perim, 20001)
    xy, heading, _ = rounded_rectangle(s, size, r)
    np.testing.assert_allclose(xy[0], xy[-1], atol=1e-9)
    assert np.abs(np.diff(xy, axis=0)).max() < 1.1 * perim / 20000
    assert heading[-1] == pytest.approx(heading[0] + 2 * np.pi)


def test_outside_time_range_is_rejected() -> None:
    traj = village_trajectory(5.0, (60.0, 45.0), 5.0, 2.0, 2.0)
    with pytest.raises(ConfigError, match="time outside the trajectory"):
        traj.evaluate([traj.t_max + 1.0])


def test_bad_inputs_are_rejected(tmp_path) -> None:
    with pytest.raises(ConfigError, match="corner radius"):
        rounded_rectangle([0.0], (10.0, 10.0), 6.0)
    bad = tmp_path / "bad.tum"
    bad.write_text("# t x y z qx qy qz qw\n0 1 2 3\n")
    with pytest.raises(DatasetError, match="TUM trajectory"):
        read_tum(bad)
    with pytest.raises(ConfigError, match="control points"):
        SplineTrajectory(0.0, 0.1, np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)))


@pytest.mark.realdata  # a trajectory of ../shared/data/trajectories
def test_tum_spline_follows_the_file() -> None:
    path = TRAJECTORIES / "euroc_V1_02_medium_groundtruth.tum"
    t, p, q = read_tum(path)
    traj = tum_trajectory(path, 20.0)
    knot = 0.05
    tt = np.arange(0.0, 20.0, 0.5)
    s = traj.evaluate(tt)
    # spline time t is file time t + knot (see tum_trajectory)
    p_file = np.column_stack([np.interp(tt + knot + t[0], t, p[:, k]) for k in range(3)])
    assert np.abs(s.p_W_B - p_file).max() < 0.01
    k = np.searchsorted(t, tt + knot + t[0])  # nearest later file sample (5 ms away at most)
    R_file = quat_to_rotmat(q[k])
    angle = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", R_file, s.R_W_B)), axis=1)
    assert angle.max() < 0.02


def test_a_trajectory_in_millimetres_is_refused_before_the_world_is_built(tmp_path) -> None:
    """A TUM file with its positions in millimetres asked for 76 GiB building the world
    around it (a user's probe); refused naming the speed and the unit."""
    from svains.datasets.trajectory import read_tum, write_tum

    t, p, q = read_tum(TRAJECTORIES / "euroc_V1_02_medium_groundtruth.tum")
    write_tum(tmp_path / "mm.tum", t, p * 1000.0, q)
    with pytest.raises(DatasetError, match=r"mm\.tum: its poses move at up to \d+ m/s over "
                       r"\d+ m .*positions in millimetres\? TUM files hold metres"):  # fmt: skip
        tum_trajectory(tmp_path / "mm.tum", duration_s=10.0)
    tum_trajectory(TRAJECTORIES / "euroc_V1_02_medium_groundtruth.tum", duration_s=10.0)


def test_stops_hold_the_vehicle_at_rest_unshaken_and_ease_in_and_out() -> None:
    """``trajectory.stops``: a static start (a stop from 0 s) and a stop mid-flight; at rest
    the speed, the rates and the shaking are zero, between them the cruise speed; the ramps
    are smooth (no jump of acceleration beyond the cosine's)."""
    from svains.sim.config import SimConfig

    traj = village_trajectory(30.0, (60.0, 45.0), 5.0, 2.0, 2.0, seed=1,
                              stops=[[0.0, 4.0], [14.0, 5.0]], stop_ramp_s=2.0)  # fmt: skip
    t = np.arange(0.0, 30.0, 0.01)
    s = traj.evaluate(t)
    speed = np.linalg.norm(s.v_W_B, axis=1)
    rest = (t < 3.9) | ((t > 14.1) & (t < 18.9))
    assert speed[rest].max() < 1e-9 and np.abs(s.omega_B[rest]).max() < 1e-9
    # the specific force at rest is gravity alone: a static start's rest test passes
    np.testing.assert_allclose(np.linalg.norm(s.specific_force_B(G_W)[rest], axis=1), 9.81,
                               atol=1e-9)  # fmt: skip
    cruise = ((t > 6.5) & (t < 11.5)) | (t > 21.5)
    assert np.abs(speed[cruise] - 2.0).max() < 0.02
    # half-cosine ramps of 2 s from 2 m/s: |a| up to pi/2 m/s² along the path
    assert np.abs(np.linalg.norm(s.a_W, axis=1)).max() < 2.0
    for stops, said in (([[3.0]], r"must be \[start_s, duration_s\] pairs"),
                        ([2.0, 3.0], r"must be \[start_s, duration_s\] pairs"),  # flat: a review
                        ([[200.0, 3.0]], r"the stop \[200.0, 3.0\] starts after the flight"),
                        # ramps overlapping: a 0.04 m/s crawl between them (a user's probe)
                        ([[13.0, 2.0], [10.0, 2.0]],
                         r"the stops \[10.0, 2.0\] and \[13.0, 2.0\] are less than two ramps "
                         r"apart \(2 x stop_ramp_s = 4 s\)")):
        cfg = SimConfig()
        cfg.trajectory.stops = stops  # type: ignore[assignment]
        with pytest.raises(ConfigError, match=said):
            cfg.validate()


def test_a_stops_speed_ramps_ease_without_a_jump_of_acceleration() -> None:
    """``speed_profile``: half a cosine over the ramp (zero slope at both of its ends, half the
    speed in its middle), zero inside the stop, one beyond; a stop from 0 s is a static start."""
    from svains.sim.trajectory import speed_profile

    ramp = 2.0
    t = np.array([2.0, 2.001, 3.0, 3.999, 4.0, 5.0, 6.0, 6.001, 7.0, 7.999, 8.0, 9.0])
    f = speed_profile(t, [[4.0, 2.0]], ramp)
    np.testing.assert_allclose(f[[0, 4, 5, 6, 10, 11]], [1.0, 0.0, 0.0, 0.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(f[[2, 8]], 0.5, atol=1e-12)
    # slopes at the ramp's ends: zero to first order (a linear ramp has 1/ramp there)
    assert abs(f[0] - f[1]) < 1e-5 and abs(f[3] - f[4]) < 1e-5
    assert abs(f[6] - f[7]) < 1e-5 and abs(f[9] - f[10]) < 1e-5
    np.testing.assert_allclose(speed_profile(np.array([-5.0, 0.0, 2.9]), [[0.0, 3.0]], ramp), 0.0)
