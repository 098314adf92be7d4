"""Analytic smooth flight and an in-memory IMU/GPS/mag/sonar data set (test helper).

Position: sinusoids; attitude: ZYX Euler angles (yaw turning with the path, small roll/pitch
oscillations) with exact body rates; IMU specific force and rates computed in closed form, so
the only IMU error is the noise added here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import (
    Dataset,
    GpsCalib,
    GpsStream,
    GroundTruth,
    ImuCalib,
    ImuStream,
    MagCalib,
    MagStream,
    SonarCalib,
    SonarStream,
)
from svains.geometry.rotation import quat_exp, quat_rotate, quat_to_rotmat, rotmat_to_quat

F64 = NDArray[np.float64]
G_W = np.array([0.0, 0.0, -9.81])
M_W = np.array([0.2, 0.0, -0.4])


def truth(t: F64) -> dict[str, F64]:
    """p, v, a (N, 3) world; q (N, 4); omega_B (N, 3) at times t (N,) s."""
    t = np.asarray(t, dtype=float)
    w1, w2 = 0.2, 0.4
    p = np.stack([20 * np.sin(w1 * t), 10 * np.sin(w2 * t), 5 + 0.5 * np.sin(w1 * t)], axis=1)
    v = np.stack(
        [20 * w1 * np.cos(w1 * t), 10 * w2 * np.cos(w2 * t), 0.5 * w1 * np.cos(w1 * t)], axis=1
    )
    a = np.stack(
        [-20 * w1**2 * np.sin(w1 * t), -10 * w2**2 * np.sin(w2 * t), -0.5 * w1**2 * np.sin(w1 * t)],
        axis=1,
    )
    # Euler angles and their rates.
    yaw, dyaw = 0.3 * t + 0.5 * np.sin(0.5 * t), 0.3 + 0.25 * np.cos(0.5 * t)
    pitch, dpitch = 0.1 * np.sin(0.7 * t), 0.07 * np.cos(0.7 * t)
    roll, droll = 0.15 * np.sin(0.9 * t + 0.3), 0.135 * np.cos(0.9 * t + 0.3)
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))  # fmt: skip
    R = np.empty((len(t), 3, 3))
    R[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=1)
    R[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=1)
    R[:, 2] = np.stack([-sp, cp * sr, cp * cr], axis=1)
    omega = np.stack(
        [droll - dyaw * sp, dpitch * cr + dyaw * cp * sr, -dpitch * sr + dyaw * cp * cr], axis=1
    )
    return {"p": p, "v": v, "a": a, "R": R, "q": rotmat_to_quat(R), "omega": omega}


def make_dataset(
    duration_s: float = 60.0,
    imu_hz: float = 100.0,
    gps_hz: float = 1.0,
    seed: int = 0,
    gps_std: float = 0.5,
    gps_vel_std: float = 0.1,
    with_mag: bool = False,
    with_sonar: bool = False,
    noise_scale: float = 1.0,
    outages: tuple[tuple[float, float], ...] = (),
    p_B_G: F64 | None = None,
) -> Dataset:
    """Noisy IMU (+ GPS, optional mag/sonar) on the analytic flight, with its ground truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / imu_hz)
    tr = truth(t)
    t_ns = np.round(t * 1e9).astype(np.int64)
    gnd, grw, and_, arw = (
        2e-4 * noise_scale,
        2e-5 * noise_scale,
        2e-3 * noise_scale,
        3e-3 * noise_scale,
    )
    bg = np.array([0.003, -0.002, 0.004]) * noise_scale + np.cumsum(
        rng.normal(0, grw / np.sqrt(imu_hz), (len(t), 3)), axis=0
    )
    ba = np.array([0.05, -0.03, 0.04]) * noise_scale + np.cumsum(
        rng.normal(0, arw / np.sqrt(imu_hz), (len(t), 3)), axis=0
    )
    f_B = np.einsum("nji,nj->ni", tr["R"], tr["a"] - G_W)
    gyro = tr["omega"] + bg + rng.normal(0, gnd * np.sqrt(imu_hz), (len(t), 3))
    acc = f_B + ba + rng.normal(0, and_ * np.sqrt(imu_hz), (len(t), 3))
    ds = Dataset(root=Path("/nonexistent"), name=f"analytic-{seed}", gravity_W=G_W.copy())
    ds.imu = ImuStream(t_ns, gyro, acc)
    ds.imu_calib = ImuCalib(np.eye(4), imu_hz, gnd, grw, and_, arw)
    ds.groundtruth = GroundTruth(t_ns, tr["p"], tr["q"], tr["v"], bg, ba)
    p_B_G = np.array([0.1, 0.0, 0.2]) if p_B_G is None else p_B_G
    tg = np.arange(1.0 / gps_hz, duration_s, 1.0 / gps_hz)
    for a_s, b_s in outages:
        tg = tg[(tg < a_s) | (tg >= b_s)]
    trg = truth(tg)
    pg = trg["p"] + quat_rotate(trg["q"], p_B_G)
    vg = trg["v"] + quat_rotate(trg["q"], np.cross(trg["omega"], p_B_G))
    ds.gps = GpsStream(
        np.round(tg * 1e9).astype(np.int64),
        pg + rng.normal(0, gps_std, pg.shape),
        vg + rng.normal(0, gps_vel_std, vg.shape),
    )
    ds.gps_calib = GpsCalib(p_B_G, gps_hz, gps_std, gps_vel_std)
    if with_mag:
        tm = np.arange(0.05, duration_s, 0.1)
        trm = truth(tm)
        m_S = np.einsum("nji,j->ni", trm["R"], M_W) + rng.normal(0, 0.005, (len(tm), 3))
        ds.mag = MagStream(np.round(tm * 1e9).astype(np.int64), m_S)
        ds.mag_calib = MagCalib(np.eye(4), 10.0, M_W, 0.005)
    if with_sonar:
        ts = np.arange(0.07, duration_s, 0.1)
        trs = truth(ts)
        T_B_S = np.eye(4)
        T_B_S[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looks down (body z is up here)
        T_B_S[:3, 3] = [0.0, 0.05, -0.1]
        d_W = np.einsum("nij,j->ni", trs["R"], T_B_S[:3, 2])
        p_S = trs["p"] + np.einsum("nij,j->ni", trs["R"], T_B_S[:3, 3])
        rng_m = -p_S[:, 2] / d_W[:, 2] + rng.normal(0, 0.02, len(ts))
        ds.sonar = SonarStream(np.round(ts * 1e9).astype(np.int64), rng_m)
        ds.sonar_calib = SonarCalib(T_B_S, 10.0, 0.02, 0.0)
    return ds


def static_dataset(seed: int = 0, with_mag: bool = True, vib: float = 0.01) -> tuple[Dataset, F64]:
    """3 s at rest, tilted, with gyro bias (and magnetometer); returns it and the attitude."""
    rng = np.random.default_rng(seed)
    q = quat_exp([0.1, -0.05, 2.0])  # tilted, heading 115 deg
    R = quat_to_rotmat(q)
    t = np.arange(0.0, 3.0, 0.005)
    bg = np.array([0.01, -0.02, 0.005])
    gyro = bg + rng.normal(0, vib, (len(t), 3))
    acc = R.T @ -G_W + rng.normal(0, 5 * vib, (len(t), 3))
    ds = Dataset(root=Path("/none"), name="static", gravity_W=G_W)
    ds.imu = ImuStream((t * 1e9).astype(np.int64), gyro, acc)
    if with_mag:
        tm = np.arange(0.0, 3.0, 0.1)
        m = np.tile(R.T @ M_W, (len(tm), 1)) + rng.normal(0, 0.002, (len(tm), 3))
        ds.mag = MagStream((tm * 1e9).astype(np.int64), m)
        ds.mag_calib = MagCalib(np.eye(4), 10.0, M_W, 0.002)
    return ds, q
