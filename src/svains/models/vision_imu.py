"""IMU increment between two stereo frames for the ``rotation="imu"`` vision models.

Beyond the paper: eq. 25 writes the relative motion from the state at t_k only
(``R_k^T R_{k-1} ≈ I - Δt [ω_k]x``, ``p_k - p_{k-1} ≈ Δt v_k``). With a vibrating real IMU the
instantaneous ``ω_k`` is a poor estimate of the rotation over Δt. The gyro and accelerometer
samples between the frames give both exactly up to sensor noise, while the prediction still
depends on the state at t_k only (no cloning): see ``vision_common.ImuIncrement``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.models._quat import qexp, rotmat_rows
from svains.models.vision_common import ImuIncrement

F64 = NDArray[np.float64]


def _resample(t_ns: NDArray[np.int64], values: F64, t0_ns: int, t1_ns: int) -> tuple[F64, F64]:
    """Sample times (s, from t0) and values (N, c) on [t0, t1]: the samples inside plus linearly
    interpolated end points (held constant outside the samples' span, like ``np.interp``).
    Binary search: the cost does not grow with the length of the stream."""
    a = int(np.searchsorted(t_ns, t0_ns, side="right"))
    b = int(np.searchsorted(t_ns, t1_ns, side="left"))
    t = np.concatenate([[t0_ns], t_ns[a:b], [t1_ns]]).astype(np.int64)
    ends = _at(t_ns, values, t0_ns), _at(t_ns, values, t1_ns)
    vals = np.concatenate([ends[0][None], values[a:b], ends[1][None]])
    return (t - t0_ns) * 1e-9, vals


def _at(t_ns: NDArray[np.int64], values: F64, t_q: int) -> F64:
    """``values`` (N, c) linearly interpolated at ``t_q`` ns (c,)."""
    k = int(np.searchsorted(t_ns, t_q, side="right"))
    if k == 0:
        return values[0]
    if k == t_ns.size or t_ns[k - 1] == t_q:
        return values[k - 1]
    s = (t_q - int(t_ns[k - 1])) / (int(t_ns[k]) - int(t_ns[k - 1]))
    return (1.0 - s) * values[k - 1] + s * values[k]


def _suffix_products(M: F64) -> F64:
    """``out[i] = M[i] @ M[i+1] @ … @ M[-1]`` for matrices (K, 3, 3): a Hillis-Steele scan,
    log2(K) batched products."""
    out = M.copy()
    shift = 1
    K = M.shape[0]
    while shift < K:
        out[: K - shift] = out[: K - shift] @ out[shift:]
        shift *= 2
    return out


def imu_increment(
    t_ns: ArrayLike,
    gyro_B: ArrayLike,
    accel_B: ArrayLike,
    t0_ns: int,
    t1_ns: int,
    g_W: ArrayLike,
    bg_B: ArrayLike | None = None,
    ba_B: ArrayLike | None = None,
) -> ImuIncrement:
    """Integrate bias-corrected IMU samples over ``[t0_ns, t1_ns]`` (midpoint rule per interval).

    ``t_ns`` (N,) int64, ``gyro_B`` (N, 3) rad/s, ``accel_B`` (N, 3) specific force m/s²; the IMU
    sits at the body origin (its lever arm is neglected). Returns ``ΔR = R_{k-1}^T R_k`` and
    ``J_B = ∫ (s - t0) R_k^T R(s) f_B(s) ds`` (see ``ImuIncrement``).
    """
    t = np.asarray(t_ns, dtype=np.int64)
    bg = np.zeros(3) if bg_B is None else np.asarray(bg_B, dtype=float)
    ba = np.zeros(3) if ba_B is None else np.asarray(ba_B, dtype=float)
    # Biases are constant: remove them after the (linear) resampling.
    tf, wf = _resample(t, np.concatenate([np.asarray(gyro_B, float), np.asarray(accel_B, float)],
                                         axis=1), t0_ns, t1_ns)
    w, f = wf[:, :3] - bg, wf[:, 3:] - ba
    h = np.diff(tf)  # (K,)
    w_mid = 0.5 * (w[1:] + w[:-1])
    f_mid = 0.5 * (f[1:] + f[:-1])
    t_mid = 0.5 * (tf[1:] + tf[:-1])
    K = h.size
    phi = w_mid * h[:, None]
    # Each sub-interval [a, b]: step = R(a)^T R(b) = Exp(φ), half = R(b)^T R(mid) = Exp(-φ/2).
    rots = rotmat_rows(qexp(np.concatenate([phi, -0.5 * phi]).T).T)
    steps, half = rots[:K], rots[K:]
    # Γ(b_i) = R_k^T R(b_i) = step_{K-1}^T … step_{i+1}^T = (step_{i+1} … step_{K-1})^T.
    tail = _suffix_products(steps)  # tail[i] = step_i … step_{K-1} = R(a_i)^T R_k
    gamma_b = np.empty((K, 3, 3))
    gamma_b[-1] = np.eye(3)
    gamma_b[:-1] = np.transpose(tail[1:], (0, 2, 1))
    gamma_mid = gamma_b @ half
    # Bias Jacobians: ΔR(bg + δ) ≈ ΔR Exp(-Σ h_i Γ(b_i) δ), ∂J_B/∂ba = -Σ t_i h_i Γ(mid_i).
    th = t_mid * h
    J_B = th @ (gamma_mid @ f_mid[:, :, None])[:, :, 0]
    dJ_dba = -(th @ gamma_mid.reshape(K, 9)).reshape(3, 3)
    dR_dbg = (h @ gamma_b.reshape(K, 9)).reshape(3, 3)
    # tail[0] = R_{k-1}^T R_k.
    return ImuIncrement(
        dR_Bkm1_Bk=tail[0] if K else np.eye(3), J_B=J_B, g_W=np.asarray(g_W, dtype=float),
        bg_ref_B=bg, ba_ref_B=ba, dR_dbg=dR_dbg, dJ_dba=dJ_dba,
    )
