"""The ``tc`` vision observation model: trifocal point transfer (paper eqs. 16-21).

Three views: ``P_a = K [I | 0]`` (left, t_{k-1}), ``P_b = K [I | -b]`` (right, t_{k-1}) and, per
sigma point, ``P_c = K [R_c | -r_c]`` (left, t_k) and ``P_d = K [R_c | -r_c - b]`` (right, t_k),
with ``R_c, r_c`` from eqs. 16-18 (``svains.models.vision_common.camera_motion``).

Trifocal tensor (Hartley & Zisserman eq. 17.12, 0-based ``i``):
``T[i, q, r] = (-1)^i det [P_a without row i ; row q of P_b ; row r of P_c]``.
Point transfer (H&Z algorithm 16.2): the line ``l`` through ``p_b`` perpendicular to the epipolar
line ``F_ba p_a``, then ``p_c^r = p_a^i l_q T[i, q, r]``. For a rectified pair the epipolar line is
the row of ``p_a`` and ``l`` the column of ``p_b``: the transfer uses the disparity, like eq. 10.
Output (S, 4M) pixels, per feature ``[uL, vL, uR, vR]`` at t_k.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import skew
from svains.models.vision_common import (
    ImuIncrement,
    as_pixels,
    as_sigma_points,
    camera_motion,
)

F64 = NDArray[np.float64]

_ROW_SIGN = np.array([1.0, -1.0, 1.0])  # (-1)^(i+1) for 1-based i


def _tensor_basis(P_a: F64, P_b: F64) -> F64:
    """``G[i, q, m] = (-1)^i det[P_a w/o row i; P_b[q]; e_m]`` (3, 3, 4).

    The determinant is linear in its last row, so ``T[..., i, q, r] = G[i, q] · P_c[..., r]``:
    the state-independent part is computed once per call, the per-sigma-point part is a product.
    """
    mats = np.empty((3, 3, 4, 4, 4))
    for i in range(3):
        rows_a = np.delete(P_a, i, axis=0)
        for q in range(3):
            mats[i, q, :, 0:2, :] = rows_a
            mats[i, q, :, 2, :] = P_b[q]
            mats[i, q, :, 3, :] = np.eye(4)
    return _ROW_SIGN[:, None, None] * np.linalg.det(mats)


def trifocal_tensor(P_a: ArrayLike, P_b: ArrayLike, P_c: ArrayLike) -> F64:
    """Trifocal tensor ``T[..., i, q, r]`` (..., 3, 3, 3) of views a, b (3, 4) and c (..., 3, 4)."""
    Pa = np.asarray(P_a, dtype=float)
    Pb = np.asarray(P_b, dtype=float)
    Pc = np.asarray(P_c, dtype=float)
    if Pa.shape != (3, 4) or Pb.shape != (3, 4) or Pc.shape[-2:] != (3, 4):
        raise ValueError(f"projection matrices must be 3x4, got {Pa.shape}, {Pb.shape}, {Pc.shape}")
    return np.einsum("iqm,...rm->...iqr", _tensor_basis(Pa, Pb), Pc)


def fundamental_from_projections(P_a: ArrayLike, P_b: ArrayLike) -> F64:
    """``F_ba`` (3, 3) with ``p_b^T F_ba p_a = 0``: ``[e_b]x P_b P_a^+`` (H&Z eq. 9.1)."""
    Pa = np.asarray(P_a, dtype=float)
    Pb = np.asarray(P_b, dtype=float)
    centre_a = np.linalg.svd(Pa)[2][-1]  # null vector of P_a: camera centre of a
    e_b = Pb @ centre_a
    return skew(e_b) @ Pb @ np.linalg.pinv(Pa)


def perpendicular_lines(F_ba: F64, uv_a: F64, uv_b: F64) -> F64:
    """Lines (M, 3) through ``uv_b`` perpendicular to the epipolar lines ``F_ba p_a`` (H&Z 16.2)."""
    p_a = np.concatenate([uv_a, np.ones((len(uv_a), 1))], axis=1)
    l_e = p_a @ F_ba.T
    l1, l2 = l_e[:, 0], l_e[:, 1]
    return np.stack([l2, -l1, -uv_b[:, 0] * l2 + uv_b[:, 1] * l1], axis=1)


def transfer_points(T: ArrayLike, uv_a: ArrayLike, lines_b: ArrayLike) -> F64:
    """Point transfer ``p_c^r = p_a^i l_q T[i, q, r]`` -> pixels (..., M, 2) in view c.

    ``T`` (..., 3, 3, 3); ``uv_a`` (M, 2) px; ``lines_b`` (M, 3) lines through the view-b points.
    """
    uva = np.asarray(uv_a, dtype=float)
    p_a = np.concatenate([uva, np.ones((len(uva), 1))], axis=1)
    # Contract the state-independent indices first: (M, 3, 3) then (..., M, 3).
    al = np.einsum("mi,mq->miq", p_a, np.asarray(lines_b, dtype=float))
    p_c = np.einsum("miq,...iqr->...mr", al, np.asarray(T, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        return p_c[..., :2] / p_c[..., 2:3]


def stereo_projections(rig: RectifiedStereo) -> tuple[F64, F64]:
    """``P_a = K [I | 0]`` and ``P_b = K [I | -b]`` (3, 4) of the pair at t_{k-1} (eq. 19)."""
    K = rig.K
    P_a = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_b = K @ np.hstack([np.eye(3), np.array([[-rig.baseline], [0.0], [0.0]])])
    return P_a, P_b


def current_projections(
    X: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> tuple[F64, F64]:
    """``P_c = K [R_c | -r_c]`` and ``P_d = K [R_c | -r_c - b]`` (S, 3, 4) at t_k (eqs. 16-20)."""
    R_c, r_c = camera_motion(X, dt_s, rig, rotation, imu)
    return projections_from_motion(R_c, r_c, rig)


def projections_from_motion(R_c: F64, r_c: F64, rig: RectifiedStereo) -> tuple[F64, F64]:
    """``P_c``, ``P_d`` (S, 3, 4) from the camera motion ``R_c`` (S, 3, 3), ``r_c`` (S, 3)."""
    b = np.array([rig.baseline, 0.0, 0.0])
    K = rig.K
    P_c = K @ np.concatenate([R_c, -r_c[:, :, None]], axis=2)
    P_d = K @ np.concatenate([R_c, -(r_c + b)[:, :, None]], axis=2)
    return P_c, P_d


def predict_pixels_tc(
    X: ArrayLike,
    uv_left_prev: ArrayLike,
    uv_right_prev: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> F64:
    """TC prediction of the pixels at t_k, (S, 4M) (or (4M,) for one state), ``[uL, vL, uR, vR]``.

    ``X`` (S, nx) sigma points at t_k; ``uv_left_prev``/``uv_right_prev`` (M, 2) px tracked at
    t_{k-1}; ``dt_s`` s between frames; ``rotation`` "linear" (paper, eq. 18), "exp" or "imu"
    (with ``imu``, see ``vision_common.camera_motion``).
    """
    _, single = as_sigma_points(X)
    R_c, r_c = camera_motion(X, dt_s, rig, rotation, imu)
    out = pixels_tc_from_motion(R_c, r_c, uv_left_prev, uv_right_prev, rig)
    return out[0] if single else out


def pixels_tc_from_motion(
    R_c: F64, r_c: F64, uv_left_prev: ArrayLike, uv_right_prev: ArrayLike, rig: RectifiedStereo
) -> F64:
    """TC pixels at t_k (S, 4M) transferred with the camera motion ``R_c`` (S, 3, 3), ``r_c``
    (S, 3) (``d_k = R_c d_{k-1} - r_c``, e.g. from a cloned pose) from the k-1 pixels (M, 2)."""
    uv_a = as_pixels(uv_left_prev, "uv_left_prev")
    uv_b = as_pixels(uv_right_prev, "uv_right_prev")
    if uv_a.shape != uv_b.shape:
        raise ValueError(f"uv_left_prev {uv_a.shape} and uv_right_prev {uv_b.shape} differ")
    P_a, P_b = stereo_projections(rig)
    P_c, P_d = projections_from_motion(R_c, r_c, rig)
    # One tensor over both target views: r indexes the 6 rows of [P_c; P_d].
    T = np.einsum("iqm,srm->siqr", _tensor_basis(P_a, P_b), np.concatenate([P_c, P_d], axis=1))
    lines = perpendicular_lines(fundamental_from_projections(P_a, P_b), uv_a, uv_b)
    p_a = np.concatenate([uv_a, np.ones((len(uv_a), 1))], axis=1)
    al = np.einsum("mi,mq->miq", p_a, lines)
    p_cd = np.einsum("miq,siqr->smr", al, T)  # (S, M, 6): homogeneous left then right
    with np.errstate(divide="ignore", invalid="ignore"):
        uv_c = p_cd[..., 0:2] / p_cd[..., 2:3]
        uv_d = p_cd[..., 3:5] / p_cd[..., 5:6]
    return np.concatenate([uv_c, uv_d], axis=-1).reshape(uv_c.shape[0], -1)
