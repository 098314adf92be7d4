"""The ``3d`` vision observation model (paper eqs. 22-26) and its exact-rotation variant.

A feature triangulated at stereo frame k-1 (eq. 10), ``d = p_Ckm1_F`` in left-camera components,
is moved rigidly to frame k with the state at k only (eq. 25)::

    d(t_k) = d - Δt C^T [ R_W_B(t_k)^T v_W_B(t_k) + ω_B(t_k) × (c_B + C d) ]

and reprojected to the left and right images (eq. 26). Output: (S, 4M) pixels, per feature
``[uL, vL, uR, vR]`` (see ``svains.models.vision_common``).

**Small-motion approximation.** Eq. 25 replaces ``R(t_k)^T R(t_{k-1}) = Exp(-∫ω dt)`` by
``I - Δt [ω(t_k)]x`` and ``r(t_k) - r(t_{k-1})`` by ``Δt v(t_k)``. The point error is second
order in Δt:

    |δd| <= ½ (Δt |ω|)² |c_B + C d| + ½ Δt² |a_W| + ½ Δt² |α| |c_B + C d| + O(Δt³)

(a: acceleration, α: angular acceleration), i.e. ``f |δd| / z`` in pixels. The exact variant
``predict_pixels_3d_exact`` uses the previous attitude (and optionally position) instead, e.g. from
a cloned state (stochastic cloning, the paper's named future work).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import quat_to_rotmat
from svains.models.state import P, Q, V, W
from svains.models.vision_common import (
    ImuIncrement,
    as_points,
    as_sigma_points,
    camera_motion,
    project_stereo,
)

F64 = NDArray[np.float64]


def propagate_points_3d(
    X: ArrayLike,
    p_Ckm1_F: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> F64:
    """Eq. 25: feature points at k in left-camera components, (S, M, 3) m.

    ``X`` (S, nx) sigma points at t_k; ``p_Ckm1_F`` (M, 3) m triangulated at t_{k-1}; ``dt_s`` s.
    ``rotation="exp"`` replaces eq. 18's ``I - Δt [C^T ω]x`` by ``Exp(-Δt C^T ω)`` (exact for a
    constant body rate), i.e. ``d_k = R_c d - r_c`` with eqs. 15-16; ``rotation="imu"`` takes the
    relative motion from the IMU increment ``imu`` (see ``vision_common.camera_motion``).
    """
    x, _ = as_sigma_points(X)
    d = as_points(p_Ckm1_F)
    if rotation != "linear":
        R_c, r_c = camera_motion(x, dt_s, rig, rotation, imu)
        return move_points(R_c, r_c, d)
    C = np.asarray(rig.R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    R_W_B = quat_to_rotmat(x[:, Q])
    v_B = np.einsum("sji,sj->si", R_W_B, x[:, V])  # R^T v_W, (S, 3)
    p_B_F = c_B + d @ C.T  # c_B + C d, (M, 3)
    omega_B = x[:, W]
    inner = v_B[:, None, :] + np.cross(omega_B[:, None, :], p_B_F[None, :, :])  # (S, M, 3)
    # C^T y == y @ C for row vectors y.
    return d[None, :, :] - dt_s * (inner @ C)


def move_points(R_c: F64, r_c: F64, p_Ckm1_F: F64) -> F64:
    """Eq. 15 for every sigma point: ``d_k = R_c d - r_c``, (S, M, 3) m.

    ``R_c`` (S, 3, 3), ``r_c`` (S, 3) from ``vision_common.camera_motion``; ``p_Ckm1_F`` (M, 3).
    """
    return p_Ckm1_F @ np.swapaxes(R_c, -1, -2) - r_c[:, None, :]


def pixels_from_motion(R_c: F64, r_c: F64, p_Ckm1_F: F64, rig: RectifiedStereo) -> F64:
    """``3d`` pixels (S, 4M) from the camera motion of each sigma point (eqs. 15, 26).

    The same prediction as ``predict_pixels_3d`` once ``R_c, r_c`` are known (for
    ``rotation="linear"`` eq. 25 is ``R_c = I - Δt [C^T ω]x``, equal up to rounding), so an
    updater that also needs the motion at the mean computes it once.
    """
    return project_stereo(move_points(R_c, r_c, p_Ckm1_F), rig)


def predict_pixels_3d(
    X: ArrayLike,
    p_Ckm1_F: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> F64:
    """Eqs. 25-26: predicted pixels at t_k, (S, 4M) (or (4M,) for a single state (nx,)).

    Per feature ``[uL, vL, uR, vR]`` px. ``X`` sigma points at t_k (any layout of
    ``svains.models.state``); ``p_Ckm1_F`` (M, 3) m in the left camera at t_{k-1}; ``dt_s`` the
    time between the two stereo frames; ``rotation`` "linear" (paper), "exp" or "imu" (with
    ``imu``, the IMU increment between the frames).
    """
    _, single = as_sigma_points(X)
    out = project_stereo(propagate_points_3d(X, p_Ckm1_F, dt_s, rig, rotation, imu), rig)
    return out[0] if single else out


def propagate_points_3d_exact(
    X: ArrayLike,
    p_Ckm1_F: ArrayLike,
    rig: RectifiedStereo,
    R_W_Bkm1: ArrayLike,
    p_W_Bkm1: ArrayLike | None = None,
    dt_s: float | None = None,
) -> F64:
    """Exact rigid motion of the points to t_k, (S, M, 3) m, left-camera components.

    ``R_W_Bkm1`` (3, 3) or (S, 3, 3): body attitude at t_{k-1}; ``p_W_Bkm1`` (3,) or (S, 3): body
    position at t_{k-1}. Without ``p_W_Bkm1`` the displacement is the paper's ``Δt v_W_B(t_k)``
    (then ``dt_s`` is required), so only the rotation is exact.
    """
    x, _ = as_sigma_points(X)
    d = as_points(p_Ckm1_F)
    C = np.asarray(rig.R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    R_W_Bk = quat_to_rotmat(x[:, Q])  # (S, 3, 3)
    R_km1 = np.broadcast_to(np.asarray(R_W_Bkm1, dtype=float), R_W_Bk.shape)
    if p_W_Bkm1 is None:
        if dt_s is None:
            raise ValueError("dt_s is required when p_W_Bkm1 is not given")
        dp_W = dt_s * x[:, V]
    else:
        dp_W = x[:, P] - np.broadcast_to(np.asarray(p_W_Bkm1, dtype=float), x[:, P].shape)
    p_B_F = c_B + d @ C.T  # (M, 3), feature in body at k-1
    # Feature relative to B(t_k), world components: R_{k-1} (c + C d) - (p_k - p_{k-1}).
    rel_W = np.einsum("sij,mj->smi", R_km1, p_B_F) - dp_W[:, None, :]
    rel_B = np.einsum("sji,smj->smi", R_W_Bk, rel_W)  # R_k^T rel_W
    return (rel_B - c_B) @ C


def predict_pixels_3d_exact(
    X: ArrayLike,
    p_Ckm1_F: ArrayLike,
    rig: RectifiedStereo,
    R_W_Bkm1: ArrayLike,
    p_W_Bkm1: ArrayLike | None = None,
    dt_s: float | None = None,
) -> F64:
    """Exact-rotation ``3d`` prediction (issue item 3): (S, 4M) pixels, order as eq. 26.

    Same as ``predict_pixels_3d`` but with ``R(t_k)^T R(t_{k-1})`` from the given previous
    attitude (a cloned state) instead of ``I - Δt [ω]x``; see ``propagate_points_3d_exact``.
    """
    _, single = as_sigma_points(X)
    pts = propagate_points_3d_exact(X, p_Ckm1_F, rig, R_W_Bkm1, p_W_Bkm1, dt_s)
    out = project_stereo(pts, rig)
    return out[0] if single else out
