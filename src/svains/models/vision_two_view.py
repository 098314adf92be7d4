"""Two-view ``3d`` observation: a feature seen in both stereo frames, its point marginalised.

The paper's ``3d`` model (``vision_3d``) triangulates each feature from the k-1 stereo pair and
takes that point as exact; its noise only widens ``R``. With disparities of a few pixels the
point is a noisy regressor, and the fused translation is attenuated (errors in variables: on the
simulator the ``3d`` speed came out ~0.4 % low). Here the point is estimated from all 8 pixels
of both frames (``[uL, vL, uR, vR]`` at k-1, then at k) at the prior's mean camera motion, and
only the 5 combinations of the 8 pixels that do not depend on the point to first order are
fused (the left null space of the point Jacobian, as in the MSCKF of Mourikis and Roumeliotis).

The point is held in inverse depth in the left camera at k-1, ``a = (α, β, ρ)`` with
``p_Ckm1_F = (α, β, 1) / ρ``: every projection stays finite for far points (ρ → 0), and the
stereo baseline keeps the point Jacobian full rank. For a camera motion ``d_k = R_c d - r_c``
(``vision_common.camera_motion``) the k point scaled by ρ is ``q = R_c (α, β, 1) - ρ r_c``, so

    uL = f qx/qz + cu,  vL = vR = f qy/qz + cv,  uR = f (qx - b ρ)/qz + cu

and at k-1 (``R_c = I``, ``r_c = 0``) ``uL = f α + cu``, ``uR = f (α - b ρ) + cu``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.geometry.camera import RectifiedStereo

F64 = NDArray[np.float64]

NUM_PIXELS = 8  # per feature: [uL, vL, uR, vR] at k-1, then at k
NUM_FUSED = 5  # 8 pixels minus the point's 3 unknowns


def inverse_depth(p_C_F: F64) -> F64:
    """Points (M, 3) m in a camera -> ``(α, β, ρ)`` (M, 3): ``x/z, y/z, 1/z`` (1/m)."""
    z = p_C_F[:, 2]
    return np.stack([p_C_F[:, 0] / z, p_C_F[:, 1] / z, 1.0 / z], axis=-1)


def _scaled_points(R_c: F64, r_c: F64, a_F: F64) -> F64:
    """``q = R_c (α, β, 1) - ρ r_c``: (S, M, 3) for ``R_c`` (S, 3, 3), ``r_c`` (S, 3)."""
    bearing = np.concatenate([a_F[:, :2], np.ones((a_F.shape[0], 1))], axis=1)  # (M, 3)
    return bearing @ np.swapaxes(R_c, -1, -2) - a_F[None, :, 2:3] * r_c[:, None, :]


def two_view_pixels(
    R_c: F64, r_c: F64, a_F: F64, rig: RectifiedStereo, q: F64 | None = None
) -> F64:
    """Predicted pixels (S, M, 8) px: ``[uL, vL, uR, vR]`` at k-1, then at k.

    ``R_c`` (S, 3, 3), ``r_c`` (S, 3) m: the left camera's motion k-1 -> k of each sigma point
    (``d_k = R_c d - r_c``); ``a_F`` (M, 3) the points in inverse depth at k-1; ``q`` their
    ``_scaled_points`` if the caller has them.
    """
    f, b = rig.f, rig.baseline
    S, M = R_c.shape[0], a_F.shape[0]
    out = np.empty((S, M, NUM_PIXELS))
    rho = a_F[:, 2]
    # The k-1 pixels do not depend on the motion: computed once, copied to every sigma point.
    before = np.empty((M, 4))
    before[:, 0] = f * a_F[:, 0] + rig.cu
    before[:, 1] = f * a_F[:, 1] + rig.cv
    before[:, 2] = before[:, 0] - f * b * rho
    before[:, 3] = before[:, 1]
    out[:, :, :4] = before
    q = _scaled_points(R_c, r_c, a_F) if q is None else q
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = f / q[..., 2]
    out[:, :, 4] = q[..., 0] * inv + rig.cu
    out[:, :, 5] = q[..., 1] * inv + rig.cv
    out[:, :, 6] = out[:, :, 4] - b * rho * inv
    out[:, :, 7] = out[:, :, 5]
    return out


def point_jacobian(
    R_c: F64, r_c: F64, a_F: F64, rig: RectifiedStereo, q: F64 | None = None
) -> F64:
    """``∂ pixels / ∂ (α, β, ρ)`` (M, 8, 3) at one camera motion ``R_c`` (3, 3), ``r_c`` (3,)
    (``q`` (M, 3): the points' ``_scaled_points`` if the caller has them)."""
    f, b = rig.f, rig.baseline
    M = a_F.shape[0]
    rho = a_F[:, 2]
    J = np.zeros((M, NUM_PIXELS, 3))
    J[:, 0, 0] = J[:, 2, 0] = f
    J[:, 1, 1] = J[:, 3, 1] = f
    J[:, 2, 2] = -f * b
    q = _scaled_points(R_c[None], r_c[None], a_F)[0] if q is None else q  # (M, 3)
    D = np.concatenate([np.broadcast_to(R_c[:, :2], (M, 3, 2)),
                        np.broadcast_to(-r_c[:, None], (M, 3, 1))], axis=2)  # ∂q/∂a, (M, 3, 3)
    inv = f / q[:, 2]
    # ∂ (f qx/qz, f qy/qz, f (qx - bρ)/qz) / ∂q
    dq = np.zeros((M, 3, 3))
    dq[:, 0, 0] = dq[:, 2, 0] = inv
    dq[:, 1, 1] = inv
    dq[:, 0, 2] = -inv * q[:, 0] / q[:, 2]
    dq[:, 1, 2] = -inv * q[:, 1] / q[:, 2]
    dq[:, 2, 2] = -inv * (q[:, 0] - b * rho) / q[:, 2]
    Jk = dq @ D  # (M, 3, 3) rows uL, vL, uR at k
    Jk[:, 2, 2] -= b * inv  # uR's own ρ term
    J[:, 4:7] = Jk
    J[:, 7] = Jk[:, 1]
    return J


def refine_points(
    a_F: F64, z_F: F64, R_c: F64, r_c: F64, rig: RectifiedStereo, iterations: int = 3
) -> F64:
    """Gauss-Newton on the 8 pixels of each feature: inverse-depth points (M, 3).

    ``a_F`` (M, 3) start (the k-1 stereo point), ``z_F`` (M, 8) px the tracked pixels,
    ``R_c`` (3, 3), ``r_c`` (3,) the mean camera motion k-1 -> k.
    """
    a = a_F.copy()
    R1, r1 = R_c[None], r_c[None]
    for _ in range(iterations):
        q = _scaled_points(R1, r1, a)  # shared by the pixels and their Jacobian
        r = z_F - two_view_pixels(R1, r1, a, rig, q)[0]
        J = point_jacobian(R_c, r_c, a, rig, q[0])
        JT = np.swapaxes(J, 1, 2)
        A = JT @ J
        g = (JT @ r[:, :, None])[:, :, 0]
        ok = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(g).all(axis=1)
        if ok.all():  # the usual case: no copies (each system is solved on its own either way)
            a += _solve_normal(A, g)
            continue
        if not ok.any():
            break
        step = np.zeros_like(a)
        step[ok] = _solve_normal(A[ok], g[ok])
        a += step
    return a


def _solve_normal(A: F64, g: F64) -> F64:
    """Steps (M, 3) of the normal equations ``A`` (M, 3, 3) ``g`` (M, 3). A feature whose ``A``
    is singular (a point along the baseline or at infinity, a pixel with no pull on one
    coordinate) gets a Levenberg-damped step instead of stopping the run: ``g`` lies in the
    range of ``A = JᵀJ``, so the damped step is the least-squares one."""
    try:
        return np.linalg.solve(A, g[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        scale = np.trace(A, axis1=1, axis2=2) / 3.0
        damp = 1e-9 * scale + np.finfo(float).tiny
        return np.linalg.solve(A + damp[:, None, None] * np.eye(3), g[:, :, None])[:, :, 0]


def null_space(J: F64) -> F64:
    """Orthonormal bases (M, 8, 5) of the left null space of each point Jacobian (M, 8, 3)."""
    Q, _ = np.linalg.qr(J, mode="complete")
    return Q[:, :, J.shape[2]:]
