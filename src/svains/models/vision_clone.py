"""Exact relative-motion vision models from a cloned pose (stochastic cloning, beyond the paper).

The state carries the body pose at the previous frame as a clone (``models.clones``): columns
``(p_W_Bkm1, q_W_Bkm1_wxyz)`` of every sigma point. The left camera's motion k-1 -> k is then
exact, with no small-motion or IMU-increment approximation::

    R_c = C^T R_k^T R_km1 C
    r_c = C^T (c_B + R_k^T (p_k - p_km1) - R_k^T R_km1 c_B)      d_k = R_c d_{k-1} - r_c

(``C`` = ``R_B_C``, ``c_B`` = ``p_B_C``, eq. 15's convention). With an online camera-IMU
rotation correction ``δφ_C`` (rad, left-camera axes) in the state, ``C = R_B_C Exp(δφ_C)`` per
sigma point (the whole stereo rig turns; ``navigation.vision_clones``). The ``3d``, ``tc`` and
``lc`` predictions follow from it as from the paper's ``camera_motion``; ``3d`` equals
``vision_3d.predict_pixels_3d_exact`` with the clone's pose (tests check it).

**Camera-IMU time offset** ``t_d`` (s, Kalibr's ``t_imu = t_cam + t_d``; ``td`` a pair: its
column in the state and the frame's ``ShiftIncrement``, ``models.time_offset``): the image
stamped ``t_k`` was taken at IMU time ``t_k + t_d``, so the current pose is moved there per
sigma point (``time_offset.shifted_pose``). The clone of the k-1 frame was made the same way
(``models.clones.augment_shifted_clone_sigma``), so the relative motion is shifted at both
ends.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp, so3_log
from svains.models._quat import rotmat_rows
from svains.models.state import P, Q
from svains.models.time_offset import ShiftIncrement, ShiftTable, shifted_pose
from svains.models.vision_3d import pixels_from_motion
from svains.models.vision_common import as_points, as_sigma_points
from svains.models.vision_tc import pixels_tc_from_motion

F64 = NDArray[np.float64]


def clone_camera_motion(
    X: ArrayLike, clone: tuple[slice, slice], rig: RectifiedStereo, calib: slice | None = None,
    td: tuple[int, ShiftIncrement | ShiftTable] | None = None,
) -> tuple[F64, F64]:
    """Left-camera motion from the clone to the current pose: ``R_c`` (S, 3, 3), ``r_c`` (S, 3).

    ``X`` (S, nx) augmented sigma points (or one state (nx,)); ``clone`` the columns
    ``(p_W_B, q_W_B_wxyz)`` of the clone (``CloneManifold.columns``); ``calib`` the columns of
    the camera rotation correction ``δφ_C`` (3, rad) when the state estimates it; ``td`` the
    camera-IMU time offset's column and the frame's ``ShiftIncrement`` when the state estimates
    it (the current pose is then ``time_offset.shifted_pose``; the clone already is).
    """
    x, _ = as_sigma_points(X)
    C = np.asarray(rig.R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    cp, cq = clone
    R_k, p_k = (rotmat_rows(x[:, Q]), x[:, P]) if td is None else shifted_pose(x, *td)
    R_km1 = rotmat_rows(x[:, cq])
    dR = R_k.transpose(0, 2, 1) @ R_km1  # R_k^T R_km1 (S, 3, 3)
    dp_B = ((p_k - x[:, cp])[:, None, :] @ R_k)[:, 0]  # R_k^T (p_k - p_km1)
    r_B = c_B + dp_B - dR @ c_B
    if calib is None:
        return C.T @ dR @ C, r_B @ C
    C_s = C @ so3_exp(x[:, calib])  # (S, 3, 3)
    return C_s.transpose(0, 2, 1) @ dR @ C_s, np.einsum("sji,sj->si", C_s, r_B)


def body_displacement(R_Ck_Ckm1: ArrayLike, p_Ck_Ckm1: ArrayLike, rig: RectifiedStereo,
                      R_B_C: ArrayLike | None = None) -> F64:  # fmt: skip
    """The body's displacement k-1 -> k (3,) m in the body frame at k, ``R_k^T (p_k - p_km1)``,
    from a measured left-camera motion ``T_Ck_Ckm1`` (``R_Ck_Ckm1`` (3, 3), ``p_Ck_Ckm1`` (3,)
    m): ``clone_camera_motion`` solved for the body's motion, the lever arm ``c_B`` included;
    ``R_B_C`` (3, 3) replaces the rig's camera rotation (an estimated one)."""
    C = np.asarray(rig.R_B_C if R_B_C is None else R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    dR = C @ np.asarray(R_Ck_Ckm1, dtype=float) @ C.T  # R_k^T R_km1
    r_B = -C @ np.asarray(p_Ck_Ckm1, dtype=float)
    return np.asarray(r_B - c_B + dR @ c_B, dtype=float)


def predict_pixels_3d_clone(
    X: ArrayLike, p_Ckm1_F: ArrayLike, clone: tuple[slice, slice], rig: RectifiedStereo,
    calib: slice | None = None, td: tuple[int, ShiftIncrement | ShiftTable] | None = None,
) -> F64:
    """``3d`` pixels at t_k (S, 4M) of points (M, 3) triangulated at the clone's frame."""
    _, single = as_sigma_points(X)
    R_c, r_c = clone_camera_motion(X, clone, rig, calib, td)
    out = pixels_from_motion(R_c, r_c, as_points(p_Ckm1_F), rig)
    return out[0] if single else out


def predict_pixels_tc_clone(
    X: ArrayLike, uv_left_prev: ArrayLike, uv_right_prev: ArrayLike,
    clone: tuple[slice, slice], rig: RectifiedStereo, calib: slice | None = None,
    td: tuple[int, ShiftIncrement | ShiftTable] | None = None,
) -> F64:
    """``tc`` pixels at t_k (S, 4M) transferred from the clone frame's pixels (M, 2)."""
    _, single = as_sigma_points(X)
    R_c, r_c = clone_camera_motion(X, clone, rig, calib, td)
    out = pixels_tc_from_motion(R_c, r_c, uv_left_prev, uv_right_prev, rig)
    return out[0] if single else out


def predict_egomotion_clone(
    X: ArrayLike, clone: tuple[slice, slice], rig: RectifiedStereo, calib: slice | None = None,
    td: tuple[int, ShiftIncrement | ShiftTable] | None = None,
) -> F64:
    """``lc``'s ``(Log R_Ck_Ckm1, p_Ck_Ckm1)`` (S, 6) between the clone and now (eqs. 30-33
    with the exact motion: ``R_Ck_Ckm1 = R_c``, ``p_Ck_Ckm1 = -r_c``)."""
    _, single = as_sigma_points(X)
    R_c, r_c = clone_camera_motion(X, clone, rig, calib, td)
    out = np.concatenate([so3_log(R_c), -r_c], axis=1)
    return out[0] if single else out
