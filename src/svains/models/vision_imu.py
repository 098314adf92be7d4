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

from svains.geometry.rotation import so3_exp
from svains.models.vision_common import ImuIncrement

F64 = NDArray[np.float64]


def _resample(t_ns: NDArray[np.int64], values: F64, t0_ns: int, t1_ns: int) -> tuple[F64, F64]:
    """Sample times (s, from t0) and values (N, 3) on [t0, t1]: the samples inside plus linearly
    interpolated end points."""
    inner = (t_ns > t0_ns) & (t_ns < t1_ns)
    t = np.concatenate([[t0_ns], t_ns[inner], [t1_ns]]).astype(np.int64)
    tf = (t - t0_ns) * 1e-9
    ts = (t_ns - t0_ns) * 1e-9
    vals = np.column_stack([np.interp(tf, ts, values[:, j]) for j in range(3)])
    return tf, vals


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
    tf, w = _resample(t, np.asarray(gyro_B, dtype=float) - bg, t0_ns, t1_ns)
    _, f = _resample(t, np.asarray(accel_B, dtype=float) - ba, t0_ns, t1_ns)
    h = np.diff(tf)  # (K,)
    w_mid = 0.5 * (w[1:] + w[:-1])
    f_mid = 0.5 * (f[1:] + f[:-1])
    t_mid = 0.5 * (tf[1:] + tf[:-1])
    steps = so3_exp(w_mid * h[:, None])  # R(a)^T R(b) of each sub-interval [a, b]
    half = so3_exp(-0.5 * w_mid * h[:, None])  # R(b)^T R(mid)
    # Backward from t_k: Γ(b) = R_k^T R(b); Γ(a) = Γ(b) step^T.
    # Bias Jacobians: ΔR(bg + δ) ≈ ΔR Exp(-Σ h_i Γ(b_i) δ), ∂J_B/∂ba = -Σ t_i h_i Γ(mid_i).
    gamma_b = np.eye(3)
    J_B = np.zeros(3)
    dR_dbg = np.zeros((3, 3))
    dJ_dba = np.zeros((3, 3))
    for i in range(len(h) - 1, -1, -1):
        gamma_mid = gamma_b @ half[i]
        J_B += t_mid[i] * h[i] * (gamma_mid @ f_mid[i])
        dJ_dba -= t_mid[i] * h[i] * gamma_mid
        dR_dbg += h[i] * gamma_b
        gamma_b = gamma_b @ steps[i].T
    # gamma_b is now R_k^T R_{k-1}.
    return ImuIncrement(
        dR_Bkm1_Bk=gamma_b.T, J_B=J_B, g_W=np.asarray(g_W, dtype=float), bg_ref_B=bg, ba_ref_B=ba,
        dR_dbg=dR_dbg, dJ_dba=dJ_dba,
    )
