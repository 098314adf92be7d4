"""The body pose at an image's IMU time: the camera-IMU time offset ``t_d`` in the state.

Kalibr's convention: ``t_imu = t_cam + t_d``, so the image stamped ``t`` (after the offset the
calibration already applied) was taken at IMU time ``t + t_d``. The filter is propagated to the
stamp ``t``; the vision models need the pose at ``t + t_d``. Following Li & Mourikis (2014) and
OpenVINS, the pose is moved by the IMU itself over the offset's current estimate ``τ`` and to
first order over the rest ``δ = t_d - τ`` (per sigma point)::

    R(t + t_d) = R ΔR Exp(ω_τ δ)
    p(t + t_d) = p + v τ + ½ g τ² + R Δp + v_τ δ,     v_τ = v + g τ + R Δv

``ΔR, Δv, Δp`` (``ShiftIncrement``) integrate the IMU samples between ``t`` and ``t + τ``
(either side: the Navigator holds the IMU ``buffer.window_s`` past a frame before it processes
the frame) with the mean biases; ``ω_τ`` is the bias-corrected gyro at ``t + τ``. Integrating
the samples matters: a first-order move over the whole offset (``τ = 0``, ``ShiftIncrement
.first_order``) misses the motion's curvature, and on the simulated village's 3 Hz vibration it
found 42.5 ms for a 50 ms offset (``docs/results/time-offset.md``). The IMU's lever arm and the
biases' uncertainty over ``τ`` (tens of ms) are neglected.

While the offset is uncertain the sigma points' ``δ`` reach tens of ms, where the first-order
move is no better than at ``τ = 0``: early in a run with an offset far from its prior, the
filter then took the motion's curvature for evidence and settled confidently on a wrong offset
(a −50 ms offset at 5 Hz: 28 ms off with σ 1.7 ms after 1 s, still 3σ off after 60 s). A
``ShiftTable`` (``shift_table``) holds the increments at every IMU sample time around ``τ``
(one pass over the samples); each sigma point takes the node nearest its own ``t_d`` and moves
to first order over the rest only (at most half an IMU period inside the table).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.geometry.rotation import skew, so3_exp
from svains.models._quat import rotmat_rows
from svains.models.state import DP, DTH, DV, P, Q, V

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class ShiftIncrement:
    """The IMU's motion from a frame's stamp ``t`` to ``t + tau_s``, in body axes at ``t``:
    ``dR`` (3, 3), ``dv_B`` (3,) m/s, ``dp_B`` (3,) m (gravity excluded), the bias-corrected
    rate ``omega_B`` (3,) rad/s at ``t + tau_s``, gravity ``g_W`` (3,) m/s²."""

    tau_s: float
    dR: F64
    dv_B: F64
    dp_B: F64
    omega_B: F64
    g_W: F64

    @classmethod
    def first_order(cls, omega_B: F64, g_W: F64) -> ShiftIncrement:
        """No IMU samples: the whole offset moved to first order with the rate ``omega_B``."""
        z = np.zeros(3)
        return cls(0.0, np.eye(3), z, z, np.asarray(omega_B, float), np.asarray(g_W, float))


def _interp(t_s: F64, ts: F64, y: F64) -> F64:
    """``y`` (N, 3) sampled at ``ts`` (N,) linearly interpolated at ``t_s`` (K,) (held at the
    ends): (K, 3)."""
    return np.stack([np.interp(t_s, ts, y[:, i]) for i in range(3)], axis=1)


def shift_increment(
    t_ns: I64, gyro_B: F64, accel_B: F64, frame_ns: int, tau_s: float, bg_B: F64, ba_B: F64,
    g_W: F64,
) -> ShiftIncrement:
    """The ``ShiftIncrement`` from ``frame_ns`` to ``frame_ns + tau_s`` of the IMU samples
    ``t_ns`` (N,), ``gyro_B``, ``accel_B`` (N, 3) (body axes) minus the biases ``bg_B``,
    ``ba_B`` (3,): ``shift_table``'s entry at ``tau_s`` (one integrator for both). Samples are
    interpolated, and held beyond the recorded ones (the last frames of a recording)."""
    return shift_table(t_ns, gyro_B, accel_B, frame_ns, tau_s, 0.0, bg_B, ba_B, g_W).center


@dataclass(frozen=True)
class ShiftTable:
    """``ShiftIncrement`` at K offsets: ``tau_s`` (K,) s increasing, ``dR`` (K, 3, 3), ``dv_B``,
    ``dp_B``, ``omega_B`` (K, 3), ``g_W`` (3,); ``center`` the one at the estimate ``τ``."""

    tau_s: F64
    dR: F64
    dv_B: F64
    dp_B: F64
    omega_B: F64
    g_W: F64
    center: ShiftIncrement


def shift_table(
    t_ns: I64, gyro_B: F64, accel_B: F64, frame_ns: int, tau_s: float, span_s: float,
    bg_B: F64, ba_B: F64, g_W: F64,
) -> ShiftTable:
    """The increments from ``frame_ns`` to every IMU sample time within ``tau_s ± span_s`` (s),
    and to ``tau_s`` itself, in one forward pass over the bias-corrected samples, interpolated
    at the nodes and held beyond the recorded ones: midpoint rule between nodes, integrated
    from the earliest node in its body axes, then rebased on the frame (a negative ``tau_s``
    is the inverse of the motion from ``t + tau_s`` to ``t``)."""
    ts = (np.asarray(t_ns, np.int64) - int(frame_ns)) * 1e-9
    gyro = np.asarray(gyro_B, float) - bg_B
    accel = np.asarray(accel_B, float) - ba_B
    g = np.asarray(g_W, float)
    lo, hi = min(0.0, tau_s - span_s), max(0.0, tau_s + span_s)
    inner = ts[(ts > lo) & (ts < hi)]
    nodes = np.unique(np.concatenate([[lo, 0.0, tau_s, hi], inner]))
    w, f = _interp(nodes, ts, gyro), _interp(nodes, ts, accel)
    h = np.diff(nodes)
    half = so3_exp(0.25 * (w[:-1] + w[1:]) * h[:, None])  # (K-1, 3, 3)
    fm = 0.5 * (f[:-1] + f[1:])
    K = nodes.size
    R, v, p = np.empty((K, 3, 3)), np.zeros((K, 3)), np.zeros((K, 3))
    R[0] = np.eye(3)
    for i in range(K - 1):  # the cumulative motion from ``lo``, in its body axes
        acc = R[i] @ half[i] @ fm[i]
        p[i + 1] = p[i] + v[i] * h[i] + 0.5 * acc * h[i] * h[i]
        v[i + 1] = v[i] + acc * h[i]
        R[i + 1] = R[i] @ half[i] @ half[i]
    z = int(np.flatnonzero(nodes == 0.0)[0])  # rebased on the frame: from 0 to each node
    Rz = R[z].T
    dR = Rz @ R
    dv = (v - v[z]) @ Rz.T
    dp = (p - p[z] - v[z] * nodes[:, None]) @ Rz.T
    dR[z], dv[z], dp[z] = np.eye(3), 0.0, 0.0
    c = int(np.flatnonzero(nodes == tau_s)[0])
    center = (ShiftIncrement.first_order(w[c], g) if tau_s == 0.0
              else ShiftIncrement(tau_s, dR[c], dv[c], dp[c], w[c], g))  # fmt: skip
    return ShiftTable(nodes, dR, dv, dp, w, g, center)


def shifted_pose(x: F64, td: int, inc: ShiftIncrement | ShiftTable) -> tuple[F64, F64]:
    """Body pose at IMU time ``t + t_d`` of states ``x`` (S, nx) at ``t`` (``t_d = x[:, td]``,
    s): ``R_W_B`` (S, 3, 3), ``p_W_B`` (S, 3), see the module docstring. With a ``ShiftTable``
    each state moves from the node nearest its own ``t_d``."""
    R = rotmat_rows(x[:, Q])
    t_d = x[:, td : td + 1]
    if isinstance(inc, ShiftTable):
        k = np.clip(np.searchsorted(inc.tau_s, t_d[:, 0]), 1, inc.tau_s.size - 1)
        k -= (t_d[:, 0] - inc.tau_s[k - 1]) < (inc.tau_s[k] - t_d[:, 0])
        tau = inc.tau_s[k][:, None]
        dR, dv, dp, w = inc.dR[k], inc.dv_B[k], inc.dp_B[k], inc.omega_B[k]
    else:
        tau = np.full((x.shape[0], 1), inc.tau_s)
        dR, dv, dp, w = inc.dR, inc.dv_B[None], inc.dp_B[None], inc.omega_B[None]
    d = t_d - tau  # (S, 1) s beyond the integrated part
    v_tau = x[:, V] + inc.g_W * tau + np.einsum("sij,sj->si", R, dv)
    p = (x[:, P] + x[:, V] * tau + 0.5 * inc.g_W * tau * tau
         + np.einsum("sij,sj->si", R, dp) + v_tau * d)  # fmt: skip
    return R @ dR @ so3_exp(w * d), p


def shifted_pose_jacobian(
    x: F64, ndx: int, td: int, td_tangent: int, inc: ShiftIncrement | ShiftTable
) -> tuple[F64, F64, F64]:
    """``shifted_pose`` of one state ``x`` (nx,) whose offset ``x[td]`` equals ``inc.tau_s``:
    ``p_W_B`` (3,), ``q_W_B_wxyz`` (4,), and its Jacobian ``S`` (6, ndx) over the state's
    tangent (``td_tangent`` the offset's column; rows ``(δp, δθ_B)``, attitude on the right)::

        δp' = δp + τ δv - R [Δp]x δθ + v_τ δt_d
        δθ' = ΔR^T δθ + ω_τ δt_d
    """
    from svains.geometry.rotation import rotmat_to_quat

    if isinstance(inc, ShiftTable):
        inc = inc.center
    R_s, p_s = shifted_pose(x[None, :], td, inc)
    R = rotmat_rows(x[None, Q])[0]
    tau = inc.tau_s
    S = np.zeros((6, ndx))
    S[0:3, DP] = np.eye(3)
    S[0:3, DV] = tau * np.eye(3)
    S[0:3, DTH] = -R @ skew(inc.dp_B)
    S[0:3, td_tangent] = x[V] + inc.g_W * tau + R @ inc.dv_B
    S[3:6, DTH] = inc.dR.T
    S[3:6, td_tangent] = inc.omega_B
    q = rotmat_to_quat(R_s[0])
    return p_s[0], q / np.linalg.norm(q), S
