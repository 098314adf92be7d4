"""The ``lc`` (loosely-coupled) vision measurement (paper eqs. 30-33).

The front end's egomotion ``T_Ck_Ckm1`` (``svains.frontend.types.Egomotion``:
``p_Ck = R_Ck_Ckm1 p_Ckm1 + p_Ck_Ckm1``) is the measurement of the camera motion predicted from
the state at t_k (eqs. 16-18): ``r_c = Δt C^T (R^T v_W + ω_B × c_B)`` and
``θ_c = Δt C^T ω_B``. With eq. 15, ``d_k = R_c d_{k-1} - r_c`` and ``R_c = Exp(-θ_c)``, so::

    z = (Log R_Ck_Ckm1, p_Ck_Ckm1)  (6,)    h(x) = (-θ_c, -r_c)  (S, 6)

ordered like ``Egomotion.cov`` (rotation vector [rad], then translation [m]).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_log
from svains.models.state import W
from svains.models.vision_common import ImuIncrement, as_sigma_points, camera_motion

F64 = NDArray[np.float64]


def predict_egomotion_lc(
    X: ArrayLike,
    dt_s: float,
    rig: RectifiedStereo,
    rotation: str = "linear",
    imu: ImuIncrement | None = None,
) -> F64:
    """Predicted ``(Log R_Ck_Ckm1, p_Ck_Ckm1)`` (S, 6) (or (6,) for one state), state at t_k.

    ``X`` (S, nx) sigma points; ``dt_s`` s between the two stereo frames. ``rotation="linear"``
    is the paper's ``θ_c = Δt C^T ω_B``; "exp"/"imu" use ``Log R_c`` of
    ``vision_common.camera_motion`` (with ``imu``, the IMU increment between the frames).
    """
    x, single = as_sigma_points(X)
    R_c, r_c = camera_motion(x, dt_s, rig, rotation, imu)
    if rotation == "linear":
        rot = -dt_s * (x[:, W] @ np.asarray(rig.R_B_C, dtype=float))  # -Δt C^T ω_B
    else:
        rot = so3_log(R_c)
    out = np.concatenate([rot, -r_c], axis=1)
    return out[0] if single else out


def egomotion_measurement(ego: Egomotion) -> tuple[F64, F64]:
    """Measurement ``z`` (6,) = (rotation vector of ``R_Ck_Ckm1`` rad, ``p_Ck_Ckm1`` m) and its
    covariance (6, 6) (``ego.cov``, symmetrised)."""
    cov = np.asarray(ego.cov, dtype=float)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise ValueError(f"egomotion covariance must be a finite 6x6 matrix, got shape {cov.shape}")
    z = np.concatenate([so3_log(np.asarray(ego.R_Ck_Ckm1, dtype=float)),
                        np.asarray(ego.p_Ck_Ckm1, dtype=float)])
    return z, 0.5 * (cov + cov.T)


def egomotion_from_state_pair(
    R_W_Bkm1: ArrayLike,
    p_W_Bkm1: ArrayLike,
    R_W_Bk: ArrayLike,
    p_W_Bk: ArrayLike,
    rig: RectifiedStereo,
) -> tuple[F64, F64]:
    """Exact ``(R_Ck_Ckm1 (3, 3), p_Ck_Ckm1 (3,))`` between two body poses (ground truth, tests)."""
    C = np.asarray(rig.R_B_C, dtype=float)
    c_B = np.asarray(rig.p_B_C, dtype=float)
    R_W_Ckm1 = np.asarray(R_W_Bkm1, dtype=float) @ C
    R_W_Ck = np.asarray(R_W_Bk, dtype=float) @ C
    p_W_Ckm1 = np.asarray(p_W_Bkm1, dtype=float) + np.asarray(R_W_Bkm1, dtype=float) @ c_B
    p_W_Ck = np.asarray(p_W_Bk, dtype=float) + np.asarray(R_W_Bk, dtype=float) @ c_B
    R_Ck_Ckm1 = R_W_Ck.T @ R_W_Ckm1
    p_Ck_Ckm1 = R_W_Ck.T @ (p_W_Ckm1 - p_W_Ck)
    return R_Ck_Ckm1, p_Ck_Ckm1
