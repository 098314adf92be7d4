"""Stereo visual odometry: chain frame-to-frame egomotions into camera poses (pure numpy)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion

F64 = NDArray[np.float64]


def egomotion_to_matrix(ego: Egomotion) -> F64:
    """``T_Ck_Ckm1`` (4, 4) of one egomotion."""
    T = np.eye(4)
    T[:3, :3] = ego.R_Ck_Ckm1
    T[:3, 3] = ego.p_Ck_Ckm1
    return T


def chain_egomotion(
    egomotions: Sequence[Egomotion | None], T_W_C0: F64 | None = None
) -> F64:
    """Camera poses ``T_W_Ck`` (K+1, 4, 4) from K egomotions ``T_Ck_Ckm1``:
    ``T_W_Ck = T_W_Ckm1 T_Ck_Ckm1^-1``, starting at ``T_W_C0`` (default identity).

    A ``None`` (frame without a motion measurement) repeats the previous motion (constant
    velocity), or identity if there is none yet.
    """
    T = np.eye(4) if T_W_C0 is None else np.asarray(T_W_C0, dtype=float).copy()
    out = np.empty((len(egomotions) + 1, 4, 4))
    out[0] = T
    T_last = np.eye(4)
    for k, ego in enumerate(egomotions):
        if ego is not None:
            T_last = egomotion_to_matrix(ego)
        # Inverse of a rigid transform without a general matrix inverse.
        R, p = T_last[:3, :3], T_last[:3, 3]
        T_inv = np.eye(4)
        T_inv[:3, :3] = R.T
        T_inv[:3, 3] = -R.T @ p
        T = T @ T_inv
        out[k + 1] = T
    return out


def relative_motion(T_W_Ckm1: F64, T_W_Ck: F64) -> tuple[F64, F64]:
    """True egomotion ``(R_Ck_Ckm1 (3, 3), p_Ck_Ckm1 (3,))`` between two camera poses (4, 4)."""
    T = np.linalg.inv(np.asarray(T_W_Ck, float)) @ np.asarray(T_W_Ckm1, float)
    return T[:3, :3], T[:3, 3]
