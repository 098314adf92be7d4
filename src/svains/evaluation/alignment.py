"""4-DoF (yaw + translation) trajectory alignment, the VIO convention evo does not provide.

A visual-inertial estimate observes roll and pitch through gravity, so only the rotation about
the gravity (up) axis and the translation are unobservable; aligning just those four degrees of
freedom is the fair comparison.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import ConfigError
from svains.geometry.rotation import skew

F64 = NDArray[np.float64]


def rotation_about_axis(axis: ArrayLike, angle_rad: float) -> F64:
    """Rotation matrix (3, 3) of ``angle_rad`` about the unit vector ``axis`` (Rodrigues)."""
    u = np.asarray(axis, dtype=float)
    K = skew(u)
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def align_posyaw(p_est: ArrayLike, p_ref: ArrayLike, up_W: ArrayLike = (0.0, 0.0, 1.0)) -> F64:
    """Least-squares yaw + translation taking ``p_est`` (N, 3) onto ``p_ref`` (N, 3).

    Minimises ``Σ |R_u(ψ) p_est_i + t − p_ref_i|²`` over the angle ψ about ``up_W`` and t.
    After centring both point sets (a = estimate, b = reference), the optimal angle is the
    argument of the summed cross-covariance in the plane normal to ``up_W``:
    ``ψ = atan2(Σ up·(a × b), Σ a⊥·b⊥)``; then ``t = mean(b) − R mean(a)``.
    Returns the 4x4 transform ``T`` to left-multiply the estimate's poses with.
    """
    a = np.asarray(p_est, dtype=float)
    b = np.asarray(p_ref, dtype=float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3:
        raise ConfigError(f"posyaw alignment needs two (N, 3) arrays, got {a.shape}, {b.shape}")
    if a.shape[0] < 2:
        raise ConfigError("posyaw alignment needs at least 2 matched poses")
    u = np.asarray(up_W, dtype=float)
    u = u / np.linalg.norm(u)
    mu_a, mu_b = a.mean(axis=0), b.mean(axis=0)
    ac, bc = a - mu_a, b - mu_b
    a_perp = ac - np.outer(ac @ u, u)
    b_perp = bc - np.outer(bc @ u, u)
    sin_term = float(np.sum(np.cross(a_perp, b_perp) @ u))
    cos_term = float(np.sum(a_perp * b_perp))
    psi = np.arctan2(sin_term, cos_term)
    R = rotation_about_axis(u, psi)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mu_b - R @ mu_a
    return T
