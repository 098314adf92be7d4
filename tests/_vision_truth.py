"""Exact two-frame stereo geometry for the vision-model tests (no filter, no simulator)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat, so3_exp
from svains.models.vision_lc import egomotion_from_state_pair

# Camera looking forward along body x (body: x forward, y left, z up), slightly tilted.
_R_B_C_NOMINAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def make_rig() -> RectifiedStereo:
    R_B_C = so3_exp(np.array([0.02, -0.05, 0.03])) @ _R_B_C_NOMINAL
    return RectifiedStereo(
        f=450.0, cu=370.0, cv=240.0, baseline=0.11, R_B_C=R_B_C,
        p_B_C=np.array([0.12, 0.06, -0.04]), width=752, height=480,
    )


@dataclass
class TwoFrames:
    """States at k-1/k (13-vectors), features in C_{k-1}, and their exact pixels at both frames."""

    x_km1: np.ndarray
    x_k: np.ndarray
    R_W_Bkm1: np.ndarray
    p_W_Bkm1: np.ndarray
    p_Ckm1_F: np.ndarray
    uv_left_prev: np.ndarray
    uv_right_prev: np.ndarray
    uv_left: np.ndarray
    uv_right: np.ndarray
    dt_s: float


def two_frames(
    rig: RectifiedStereo,
    dt_s: float,
    omega_B: np.ndarray,
    a_W: np.ndarray,
    n_features: int = 60,
    seed: int = 0,
) -> TwoFrames:
    """Constant body rate ``omega_B`` and constant world acceleration ``a_W`` over ``dt_s``."""
    rng = np.random.default_rng(seed)
    R0 = so3_exp(np.array([0.1, -0.2, 0.7]))
    p0 = np.array([3.0, -2.0, 2.0])
    v0 = np.array([1.5, 0.8, -0.3])
    R1 = R0 @ so3_exp(omega_B * dt_s)
    p1 = p0 + v0 * dt_s + 0.5 * a_W * dt_s**2
    v1 = v0 + a_W * dt_s
    x0 = np.concatenate([p0, v0, rotmat_to_quat(R0), omega_B])
    x1 = np.concatenate([p1, v1, rotmat_to_quat(R1), omega_B])
    d = np.column_stack([
        rng.uniform(-4.0, 4.0, n_features),
        rng.uniform(-3.0, 3.0, n_features),
        rng.uniform(5.0, 20.0, n_features),
    ])
    R_ck, p_ck = egomotion_from_state_pair(R0, p0, quat_to_rotmat(x1[6:10]), p1, rig)
    d_k = d @ R_ck.T + p_ck
    return TwoFrames(
        x_km1=x0, x_k=x1, R_W_Bkm1=R0, p_W_Bkm1=p0, p_Ckm1_F=d,
        uv_left_prev=rig.project(d), uv_right_prev=rig.project_right(d),
        uv_left=rig.project(d_k), uv_right=rig.project_right(d_k), dt_s=dt_s,
    )


def true_pixels(tf: TwoFrames) -> np.ndarray:
    """(4M,) measured pixels at k, feature-major ``[uL, vL, uR, vR]``."""
    return np.concatenate([tf.uv_left, tf.uv_right], axis=1).reshape(-1)


def sigma_cloud(x: np.ndarray, n: int = 25, seed: int = 1) -> np.ndarray:
    """``n`` perturbed states around ``x`` (unit quaternions), (n, 13)."""
    rng = np.random.default_rng(seed)
    X = np.tile(x, (n, 1))
    X[:, 0:6] += rng.normal(0.0, 0.3, (n, 6))
    X[:, 10:13] += rng.normal(0.0, 0.2, (n, 3))
    q = X[:, 6:10] + rng.normal(0.0, 0.05, (n, 4))
    X[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return X


def imu_samples(
    tf: TwoFrames, omega_B: np.ndarray, a_W: np.ndarray, g_W: np.ndarray, rate_hz: float = 200.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free gyro/accelerometer (t_ns (N,), gyro (N, 3), accel (N, 3)) of ``two_frames``'s
    motion, frame k-1 at t = 0 ns, samples slightly beyond both frames."""
    t_s = np.arange(-2, int(tf.dt_s * rate_hz) + 3) / rate_hz + 0.37 / rate_hz
    R = tf.R_W_Bkm1 @ so3_exp(t_s[:, None] * omega_B)
    accel = np.einsum("nji,j->ni", R, a_W - g_W)
    return (t_s * 1e9).round().astype(np.int64), np.tile(omega_B, (len(t_s), 1)), accel
