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
    u, sin_term, cos_term, mu_a, mu_b = _yaw_terms(a, b, up_W)
    return _yaw_transform(u, sin_term, cos_term, mu_a, mu_b)


def _yaw_terms(a: F64, b: F64, up_W: ArrayLike) -> tuple[F64, float, float, F64, F64]:
    """Unit ``up_W``, the sine and cosine sums of the positions-only yaw fit (see
    :func:`align_posyaw`) and the two centroids, for points ``a`` (estimate), ``b`` (N, 3)."""
    u = np.asarray(up_W, dtype=float)
    u = u / np.linalg.norm(u)
    mu_a, mu_b = a.mean(axis=0), b.mean(axis=0)
    ac, bc = a - mu_a, b - mu_b
    a_perp = ac - np.outer(ac @ u, u)
    b_perp = bc - np.outer(bc @ u, u)
    sin_term = float(np.sum(np.cross(a_perp, b_perp) @ u))
    return u, sin_term, float(np.sum(a_perp * b_perp)), mu_a, mu_b


def _yaw_transform(u: F64, sin_term: float, cos_term: float, mu_a: F64, mu_b: F64) -> F64:
    """4x4 transform: rotation about ``u`` by ``atan2(sin_term, cos_term)``, then the
    translation taking the rotated centroid ``mu_a`` onto ``mu_b``."""
    R = rotation_about_axis(u, np.arctan2(sin_term, cos_term))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mu_b - R @ mu_a
    return T


def align_posyaw_poses(
    p_est: ArrayLike,
    R_est: ArrayLike,
    p_ref: ArrayLike,
    R_ref: ArrayLike,
    up_W: ArrayLike = (0.0, 0.0, 1.0),
    lever_m: float = 3.0,
) -> F64:
    """Yaw + translation taking estimated poses onto reference poses (positions (N, 3) in m,
    body-in-world rotations ``R_W_B`` (N, 3, 3)), using positions *and* headings.

    Minimises ``Σ |R p_est_i + t − p_ref_i|² + lever_m² Σ ||R R_est_i − R_ref_i||_F²``: every
    pose also counts as three points ``lever_m`` along its body axes. Positions alone leave the
    yaw undetermined when the trajectory barely moves (a hovering or resting vehicle); the
    heading term then fixes it, while on a trajectory much larger than ``lever_m`` it changes the
    result of :func:`align_posyaw` negligibly. With ``K = [u]×`` and ``M = Σ R_est_i R_ref_iᵀ``,
    ``tr(R_u(ψ) M) = tr M + sin ψ tr(K M) + (1 − cos ψ) tr(K² M)``, so
    ``ψ = atan2(S + L² tr(K M), C − L² tr(K² M))`` with C, S of :func:`align_posyaw`.
    Returns the 4x4 transform to left-multiply the estimated poses with.

    ``lever_m`` weighs a heading error of θ like a position error of ``θ L``: 3 m, about the
    ratio of a visual-inertial run's position error to its heading error (0.05-0.1 m to
    0.5-1°). With 0.1 m the positions set the yaw alone wherever the vehicle moves by more than
    a few decimetres, also where they move by little more than their own error: EuRoC micro,
    ``ins`` over its first 10 s (a rest, then 0.8 m of flight), came out 32.7° off in attitude
    with a yaw NEES of 395 (0.90° and 0.0 with 3 m), and ``3d`` with frames 5 s apart at a yaw
    NEES of 6.3 (0.3). Over the whole EuRoC flight with 5 Hz frames nothing moves (NEES 6.7).
    """
    a = np.asarray(p_est, dtype=float)
    b = np.asarray(p_ref, dtype=float)
    Ra = np.asarray(R_est, dtype=float)
    Rb = np.asarray(R_ref, dtype=float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3:
        raise ConfigError(f"posyaw alignment needs two (N, 3) arrays, got {a.shape}, {b.shape}")
    if Ra.shape != (a.shape[0], 3, 3) or Rb.shape != Ra.shape:
        raise ConfigError(f"posyaw alignment needs (N, 3, 3) rotations, got {Ra.shape}, {Rb.shape}")
    if a.shape[0] < 1:
        raise ConfigError("posyaw alignment needs at least 1 matched pose")
    u, sin_term, cos_term, mu_a, mu_b = _yaw_terms(a, b, up_W)
    K = skew(u)
    M = np.einsum("nij,nkj->ik", Ra, Rb)
    w = lever_m**2
    sin_term += w * float(np.trace(K @ M))
    cos_term -= w * float(np.trace(K @ K @ M))
    return _yaw_transform(u, sin_term, cos_term, mu_a, mu_b)
