"""Vectorised rotation helpers. Hamilton quaternions, scalar first (``q_wxyz``).

Every function broadcasts over leading dimensions: a quaternion array has shape (..., 4), a
rotation vector (..., 3), a rotation matrix (..., 3, 3). ``R(q_W_B)`` maps B components to W
components. See ``docs/conventions.md``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

_SMALL_ANGLE = 1e-8


def skew(w: ArrayLike) -> Array:
    """Skew matrix ``[w]x`` with ``[w]x v = w × v``; (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros((*w.shape[:-1], 3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def quat_normalize(q_wxyz: ArrayLike) -> Array:
    """Unit quaternion with non-negative scalar part; (..., 4)."""
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_multiply(p_wxyz: ArrayLike, q_wxyz: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q``; broadcasts (..., 4) x (..., 4)."""
    p = np.asarray(p_wxyz, dtype=float)
    q = np.asarray(q_wxyz, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q_wxyz: ArrayLike) -> Array:
    """Inverse of a unit quaternion; (..., 4)."""
    q = np.array(q_wxyz, dtype=float)
    q[..., 1:] *= -1.0
    return q


def quat_to_rotmat(q_wxyz: ArrayLike) -> Array:
    """Rotation matrix of a unit quaternion; (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q_wxyz, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def rotmat_to_quat(R: ArrayLike) -> Array:
    """Unit quaternion (w >= 0) of a rotation matrix; (..., 3, 3) -> (..., 4).

    Uses scipy's robust conversion and reorders xyzw -> wxyz.
    """
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    q_xyzw = Rotation.from_matrix(flat).as_quat()
    q = np.concatenate([q_xyzw[:, 3:], q_xyzw[:, :3]], axis=1)
    return quat_normalize(q).reshape(*R.shape[:-2], 4)


def quat_exp(theta: ArrayLike) -> Array:
    """``Exp`` of a rotation vector θ (rad) as a unit quaternion; (..., 3) -> (..., 4)."""
    th = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(th, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < _SMALL_ANGLE
    # sin(a/2)/a, with its Taylor series near zero to stay exact to rounding.
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), k * th], axis=-1)


def quat_log(q_wxyz: ArrayLike) -> Array:
    """``Log`` of a unit quaternion as a rotation vector (angle in [0, π]); (..., 4) -> (..., 3)."""
    q = quat_normalize(q_wxyz)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    w = q[..., :1]
    angle = 2.0 * np.arctan2(s, w)
    small = s < _SMALL_ANGLE
    safe = np.where(small, 1.0, s)
    # Near zero w ≈ 1 (w >= 0 after normalising): 2 atan2(s, w) / s ≈ (2 / w)(1 - s² / 3w²).
    k = np.where(small, (2.0 / w) * (1.0 - s**2 / (3.0 * w**2)), angle / safe)
    return k * v


def so3_exp(theta: ArrayLike) -> Array:
    """``Exp`` of a rotation vector as a matrix (Rodrigues); (..., 3) -> (..., 3, 3)."""
    return quat_to_rotmat(quat_exp(theta))


def so3_log(R: ArrayLike) -> Array:
    """``Log`` of a rotation matrix as a rotation vector; (..., 3, 3) -> (..., 3)."""
    return quat_log(rotmat_to_quat(R))


def so3_right_jacobian_inv(theta: ArrayLike) -> Array:
    """Inverse right Jacobian of SO(3) at the rotation vector ``theta`` (3,) -> (3, 3):
    ``Log(Exp(θ) Exp(δ)) ≈ θ + J_r⁻¹(θ) δ`` for a small body perturbation ``δ`` (a
    covariance about ``Exp(θ)`` in the chart about the identity)."""
    t = np.asarray(theta, dtype=float)
    a = float(np.linalg.norm(t))
    K = skew(t)
    if a < 1e-6:
        return np.eye(3) + 0.5 * K + (K @ K) / 12.0
    c = 1.0 / a**2 - (1.0 + np.cos(a)) / (2.0 * a * np.sin(a))
    return np.eye(3) + 0.5 * K + c * (K @ K)


def quat_box_plus(q_wxyz: ArrayLike, dtheta_B: ArrayLike) -> Array:
    """Local (body) perturbation ``q ⊗ Exp(δθ_B)``, renormalised; broadcasts."""
    return quat_normalize(quat_multiply(q_wxyz, quat_exp(dtheta_B)))


def quat_box_minus(q_wxyz: ArrayLike, q_ref_wxyz: ArrayLike) -> Array:
    """Local error ``δθ_B = Log(q_ref^{-1} ⊗ q)`` so that ``q = q_ref ⊞ δθ_B``; broadcasts."""
    return quat_log(quat_multiply(quat_conjugate(q_ref_wxyz), q_wxyz))


def quat_rotate(q_wxyz: ArrayLike, v: ArrayLike) -> Array:
    """``R(q) v``; broadcasts (..., 4) with (..., 3)."""
    q = np.asarray(q_wxyz, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., 1:]
    w = q[..., :1]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_average(q_wxyz: ArrayLike, weights: ArrayLike, iterations: int = 5) -> Array:
    """Weighted mean of unit quaternions (N, 4) on the manifold (Gauss-Newton on the local error).

    Weights may be negative (unscented weights); the mean is found by iterating
    ``q̄ ← q̄ ⊞ Σ w_i Log(q̄^{-1} q_i)`` starting from the largest-weight quaternion.
    """
    q = np.asarray(q_wxyz, dtype=float)
    w = np.asarray(weights, dtype=float)
    mean = q[int(np.argmax(w))]
    for _ in range(iterations):
        err = quat_box_minus(q, mean)
        step = w @ err / w.sum()
        mean = quat_box_plus(mean, step)
        if np.linalg.norm(step) < 1e-15:
            break
    return mean
