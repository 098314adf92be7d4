"""Shared pieces of the vision observation models (paper eqs. 15-18, 26).

Every vision model predicts, for M features tracked from stereo frame k-1 to frame k, four pixel
coordinates per feature. **Ordering** of the predicted (and measured) vector, feature-major:
``[uL_0, vL_0, uR_0, vR_0, uL_1, vL_1, uR_1, vR_1, ...]`` -> length 4M. ``stack_pixels`` builds the
matching measurement vector from tracked pixels.

State layout: ``svains.models.state`` (p_W_B, v_W_B, q_W_B_wxyz, omega_B, ...). The rig places the
rectified left camera on the body with ``R_B_C`` (the paper's ``C``) and ``p_B_C`` (``c_B``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import skew, so3_exp
from svains.models._quat import qexp, rotmat_rows
from svains.models.state import BA, BG, Q, V, W

F64 = NDArray[np.float64]

ROTATION_MODELS = ("linear", "exp", "imu")


@dataclass(frozen=True)
class ImuIncrement:
    """Body motion between two stereo frames from the IMU samples (``models.vision_imu``).

    ``dR_Bkm1_Bk`` (3, 3) = ``R(t_{k-1})^T R(t_k)`` from the integrated gyro; ``J_B`` (3,) m =
    ``∫ (s - t_{k-1}) R(t_k)^T R(s) f_B(s) ds`` (specific force, body-at-k components); ``g_W``
    (3,) gravity. With them, ``R(t_k)^T (p_k - p_{k-1}) = Δt R_k^T v_k - ½ Δt² R_k^T g_W - J_B``.
    ``bg_ref_B``/``ba_ref_B``: the biases removed from the samples; a biased state's sigma points
    correct both to first order, ``ΔR Exp(-M_g δbg)`` and ``J_B + M_a δba`` with the Jacobians
    ``M_g`` = ``dR_dbg`` (3, 3) and ``M_a`` = ``dJ_dba`` (3, 3), so the vision update also
    observes the biases.
    """

    dR_Bkm1_Bk: F64
    J_B: F64
    g_W: F64
    bg_ref_B: F64 | None = None
    ba_ref_B: F64 | None = None
    dR_dbg: F64 | None = None
    dJ_dba: F64 | None = None


def as_sigma_points(X: ArrayLike) -> tuple[F64, bool]:
    """``X`` as (S, nx) float array, and whether the caller passed a single state (nx,)."""
    x = np.asarray(X, dtype=float)
    if x.ndim == 1:
        return x[None, :], True
    if x.ndim != 2 or x.shape[1] < 13:
        raise ValueError(f"state must be (nx,) or (S, nx) with nx >= 13, got shape {x.shape}")
    return x, False


def as_points(p_C_F: ArrayLike, name: str = "p_Ckm1_F") -> F64:
    """Feature points (M, 3) float array (checks the shape)."""
    p = np.asarray(p_C_F, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must be (M, 3), got shape {p.shape}")
    return p


def as_pixels(uv: ArrayLike, name: str) -> F64:
    """Pixels (M, 2) float array (checks the shape)."""
    a = np.asarray(uv, dtype=float)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"{name} must be (M, 2), got shape {a.shape}")
    return a


def camera_motion(
    X: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> tuple[F64, F64]:
    """Relative left-camera motion k-1 -> k from the state at k (eqs. 16-18).

    Returns ``R_c`` (S, 3, 3) and ``r_c`` (S, 3) m with ``d(t_k) = R_c d(t_{k-1}) - r_c`` (eq. 15),
    both in camera components: ``r_c = Δt C^T (R^T v_W + ω_B × c_B)`` and
    ``R_c = I - Δt [C^T ω_B]x`` (``rotation="linear"``, the paper's eq. 18) or the rotation
    ``Exp(-Δt C^T ω_B)`` it linearises (``rotation="exp"``). ``rotation="imu"`` (beyond the paper)
    takes the rotation and the displacement's curvature from the IMU samples between the frames
    (``imu``), still with the state at t_k only: ``R_c = C^T ΔR^T C`` and
    ``r_c = C^T (Δt R^T v_W - ½ Δt² R^T g_W - J_B + c_B - ΔR^T c_B)``.
    """
    x, _ = as_sigma_points(X)
    if rotation not in ROTATION_MODELS:
        raise ValueError(f"rotation must be one of {ROTATION_MODELS}, got {rotation!r}")
    C = np.asarray(rig.R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    # Row-major kernels (``models._quat``): same values as ``quat_to_rotmat``/``so3_exp``, fewer
    # NumPy calls at sigma-point sizes.
    R_W_B = rotmat_rows(x[:, Q])
    omega_B = x[:, W]
    v_B = (x[:, None, V] @ R_W_B)[:, 0]  # R^T v_W
    if rotation == "imu":
        if imu is None:
            raise ValueError("rotation='imu' needs the IMU increment between the frames")
        dRt = np.asarray(imu.dR_Bkm1_Bk, dtype=float).T  # R_k^T R_km1
        J_B = np.asarray(imu.J_B, dtype=float)
        if x.shape[1] >= BA.stop and imu.bg_ref_B is not None and imu.ba_ref_B is not None:
            M_g = dt_s * np.eye(3) if imu.dR_dbg is None else np.asarray(imu.dR_dbg, float)
            M_a = -0.5 * dt_s**2 * np.eye(3) if imu.dJ_dba is None else np.asarray(imu.dJ_dba)
            # (ΔR Exp(-M_g δbg))^T = Exp(M_g δbg) ΔR^T.
            dRt = rotmat_rows(qexp(((x[:, BG] - imu.bg_ref_B) @ M_g.T).T).T) @ dRt
            J_B = J_B + (x[:, BA] - imu.ba_ref_B) @ M_a.T
        g_B = R_W_B.transpose(0, 2, 1) @ np.asarray(imu.g_W, dtype=float)  # R^T g_W
        r_B = dt_s * v_B - 0.5 * dt_s**2 * g_B - J_B + c_B - dRt @ c_B
        R_c = C.T @ dRt @ C
        return np.broadcast_to(R_c, (x.shape[0], 3, 3)) if R_c.ndim == 2 else R_c, r_B @ C
    # C^T y == y @ C for row vectors y.
    r_c = dt_s * (v_B + np.cross(omega_B, c_B)) @ C
    omega_C = omega_B @ C
    # The linear form is not orthogonal; "exp" is the rotation it approximates.
    R_c = np.eye(3) - dt_s * skew(omega_C) if rotation == "linear" else so3_exp(-dt_s * omega_C)
    return R_c, r_c


def project_stereo(p_Ck_F: F64, rig: RectifiedStereo) -> F64:
    """Left and right pixels of left-camera points (S, M, 3) -> (S, 4M), feature-major order.

    Points at or behind the camera (z <= 0) give non-finite or meaningless pixels: the caller
    (the vision updater) drops such features before the update.
    """
    z = p_Ck_F[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = rig.f / z
    out = np.empty((*p_Ck_F.shape[:-1], 4))
    x_inv_z = p_Ck_F[..., 0] * inv_z
    np.add(x_inv_z, rig.cu, out=out[..., 0])
    np.multiply(p_Ck_F[..., 1], inv_z, out=out[..., 1])
    out[..., 1] += rig.cv
    # u_right = (x - b) f / z + cu = u_left - b f / z.
    np.subtract(out[..., 0], rig.baseline * inv_z, out=out[..., 2])
    out[..., 3] = out[..., 1]
    return out.reshape(*out.shape[:-2], -1)


def stack_pixels(uv_left: ArrayLike, uv_right: ArrayLike) -> F64:
    """Measurement vector (4M,) from tracked left/right pixels (M, 2), feature-major order."""
    uvl = as_pixels(uv_left, "uv_left")
    uvr = as_pixels(uv_right, "uv_right")
    if uvl.shape != uvr.shape:
        raise ValueError(f"uv_left {uvl.shape} and uv_right {uvr.shape} differ")
    return np.concatenate([uvl, uvr], axis=1).reshape(-1)


def feature_rows(m_indices: ArrayLike) -> NDArray[np.int64]:
    """Rows of the 4M vector belonging to features ``m_indices`` (K,) -> (4K,)."""
    m = np.asarray(m_indices, dtype=np.int64)
    return (4 * m[:, None] + np.arange(4)[None, :]).reshape(-1)
