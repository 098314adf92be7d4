"""IMU process model (paper eqs. 1-3), vectorised over sigma points AND over the IMU steps.

Kinematics in our sign convention (``docs/conventions.md``):
``v̇_W = g_W + R_W_B (f_B − ba_B − ω×(ω×r_BA) − α×r_BA)``, ``ṗ_W = v_W``, ``q̇ = ½ q ⊗ (0, ω_B)``.

* Paper model (13 numbers): ``ω̇_B = α``, α from the gyro by the three-point backward stencil
  (eq. 3, generalised to uneven steps). A constant gyro bias cancels in the stencil, so ω follows
  the gyro's changes from its initial value.
* Biased model (19 numbers): gyro and accelerometer biases are random-walk states. A bias state
  is only observable if the gyro's absolute value is used, so here ``ω_B = ω_gyro − bg_B`` at
  every IMU sample (the stencil α still feeds the lever-arm term).

Integration over one step of length h between nodes j, j+1: attitude by the exact exponential of
the rotation vector of a linearly varying rate, ``q_{j+1} = q_j ⊗ Exp(φ_j)``,
``φ_j = h (ω_j + ω_{j+1})/2 + h²/12 ω_j × ω_{j+1}`` (exact for a constant rate; the second term is
the coning correction; measured on 1 Hz, 0.3 rad coning: second-order global error, 4.5e-4 rad
after 10 s at 200 Hz); ω by the trapezoid rule on α; v and p by the trapezoid rule on the world
acceleration (exact for piecewise-linear acceleration). A chunk of K steps is evaluated for
all S sigma points at once: the attitude chain is a prefix product (log2 K vectorised products).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.models._quat import cross, qexp, qmul, qrot
from svains.models.state import BA, BG, DBA, DBG, DP, DTH, DV, DW, P, Q, StateLayout, V, W

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ImuChunk:
    """IMU inputs at K+1 nodes (node 0 = the current filter time), body frame B.

    ``h_s`` (K,) step lengths s; ``gyro_B`` (K+1, 3) rad/s; ``accel_B`` (K+1, 3) specific force
    at the accelerometer A, m/s²; ``alpha_B`` (K+1, 3) rad/s² (stencil, eq. 3).
    """

    h_s: F64
    gyro_B: F64
    accel_B: F64
    alpha_B: F64

    @property
    def duration_s(self) -> float:
        return float(self.h_s.sum())


@dataclass(frozen=True)
class ImuModel:
    """Process model parameters: state layout, gravity ``g_W`` (3,), lever arm ``p_B_A`` (3,) m.

    ``preintegrated`` selects ``models.imu_preint.propagate_preintegrated`` (fast, first order in
    the sigma points' rate/bias spread) instead of the exact per-sigma-point ``propagate``.
    """

    layout: StateLayout
    g_W: F64
    p_B_A: F64
    preintegrated: bool = True

    def __call__(self, X: F64, chunk: ImuChunk, dt: float = 0.0) -> F64:
        """Propagate sigma points ``X`` (S, nx) over ``chunk``; ``dt`` unused (in ``chunk``)."""
        if self.preintegrated:
            from svains.models.imu_preint import propagate_preintegrated

            return propagate_preintegrated(X, chunk, self.layout, self.g_W, self.p_B_A)
        return propagate(X, chunk, self.layout, self.g_W, self.p_B_A)


def angular_acceleration(t_s: F64, gyro_B: F64) -> F64:
    """α (N, 3) rad/s² at every sample: eq. 3's backward stencil ``(3ω_k − 4ω_{k−1} + ω_{k−2})
    / 2δt``, written for uneven spacing (identical for even spacing); first two by a difference.
    """
    t = np.asarray(t_s, dtype=float)
    g = np.asarray(gyro_B, dtype=float)
    alpha = np.zeros_like(g)
    if len(t) < 2:
        return alpha
    alpha[:2] = (g[1] - g[0]) / (t[1] - t[0])
    if len(t) > 2:
        h1 = (t[1:-1] - t[:-2])[:, None]
        h2 = (t[2:] - t[1:-1])[:, None]
        alpha[2:] = (
            g[:-2] * h2 / (h1 * (h1 + h2))
            - g[1:-1] * (h1 + h2) / (h1 * h2)
            + g[2:] * (h1 + 2.0 * h2) / (h2 * (h1 + h2))
        )
    return alpha


def stencil_consistent_rate(gyro_B: F64, k: int) -> F64:
    """Gyro value at sample k (3,) such that the paper model's ω = ω_0 + Σ trapezoid(α) tracks
    the gyro without a constant offset.

    Summing the stencil (eq. 3) telescopes: ``ω_K = ω_0 − [½(g_{k−1}+g_k) + ¼(g_k−g_{k−2})]
    + g_K + (zero-mean terms of the last samples)``. Starting from ``ω_0 = g_k`` would lock
    ``¼g_k − ½g_{k−1} + ¼g_{k−2}`` (0.6 σ of the gyro noise: 0.05 rad/s on a vibrating EuRoC
    MAV) into ω for ever; this value removes it.
    """
    if k < 2:
        return np.asarray(gyro_B[k], dtype=float)
    g = np.asarray(gyro_B, dtype=float)
    return 0.5 * (g[k - 1] + g[k]) + 0.25 * (g[k] - g[k - 2])


def _prefix_qmul(dq: F64) -> F64:
    """Inclusive prefix product along the last axis: out[..., j] = dq[..., 0] ⊗ … ⊗ dq[..., j].

    ``dq`` (4, S, K); Hillis-Steele scan, log2(K) vectorised products.
    """
    out = dq
    shift = 1
    K = dq.shape[-1]
    while shift < K:
        nxt = out.copy()
        nxt[..., shift:] = qmul(out[..., :-shift], out[..., shift:])
        out = nxt
        shift *= 2
    return out


def propagate(X: F64, chunk: ImuChunk, layout: StateLayout, g_W: F64, p_B_A: F64) -> F64:
    """State sigma points (S, nx) at the end of ``chunk`` (see the module docstring).

    Internally component-first arrays (3 or 4, S, K+1) over sigma points and IMU nodes.
    """
    h = chunk.h_s
    K = h.size
    out = np.array(X, dtype=float)
    if K == 0:
        return out
    XT = X.T  # (nx, S): rows are state components
    if layout.biased:
        omega = chunk.gyro_B.T[:, None, :] - XT[BG][:, :, None]
    else:
        steps = 0.5 * h[:, None] * (chunk.alpha_B[:-1] + chunk.alpha_B[1:])
        c = np.zeros((K + 1, 3))
        np.cumsum(steps, axis=0, out=c[1:])
        omega = XT[W][:, :, None] + c.T[:, None, :]
    # Attitude at the nodes: q_j = q_0 ⊗ Exp(h_0 ω̄_0) ⊗ … ⊗ Exp(h_{j-1} ω̄_{j-1}).
    w0, w1 = omega[..., :-1], omega[..., 1:]
    dq = _prefix_qmul(qexp(0.5 * (w0 + w1) * h + (h * h / 12.0) * cross(w0, w1)))
    q0 = XT[Q][:, :, None]
    q = np.concatenate([q0, qmul(q0, dq)], axis=2)
    # Specific force at B: accelerometer minus lever-arm terms (and bias), rotated to W.
    r = np.asarray(p_B_A, dtype=float)[:, None, None]
    f = chunk.accel_B.T[:, None, :] - cross(omega, cross(omega, r))
    f -= cross(chunk.alpha_B.T, r[:, :, 0])[:, None, :]
    if layout.biased:
        f -= XT[BA][:, :, None]
    a_W = qrot(q, f) + np.asarray(g_W, dtype=float)[:, None, None]
    # Trapezoid on v; exact integral of a piecewise-linear acceleration for p.
    dv = (0.5 * h) * (a_W[..., :-1] + a_W[..., 1:])
    dv_cum = np.cumsum(dv, axis=2)
    v0 = XT[V]
    dp = (h * h / 6.0) * (2.0 * a_W[..., :-1] + a_W[..., 1:])
    dp_total = v0 * h.sum() + (dv_cum[..., :-1] * h[1:]).sum(axis=2) + dp.sum(axis=2)
    out[:, P] = (XT[P] + dp_total).T
    out[:, V] = (v0 + dv_cum[..., -1]).T
    qe = q[..., -1]
    out[:, Q] = (qe / np.sqrt((qe * qe).sum(axis=0))).T
    out[:, W] = omega[..., -1].T
    return out


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise densities (EuRoC ``sensor.yaml`` names), SI units."""

    gyro_noise_density: float  # rad/s/√Hz
    gyro_random_walk: float  # rad/s²/√Hz
    accel_noise_density: float  # m/s²/√Hz
    accel_random_walk: float  # m/s³/√Hz


# Variance, in units of σ_g²/h, of the gyro white noise left in the paper model's ω: summing the
# stencil (eq. 3) with the trapezoid anchors ω to ¾g_K + ½g_{K−1} − ¼g_{K−2} (see
# ``stencil_consistent_rate``), whose white-noise variance is (9 + 4 + 1)/16 = 0.875 σ_g²/h.
STENCIL_RATE_VARIANCE = 0.875


def omega_white_variance(layout: StateLayout, noise: ImuNoise, h_imu_s: float) -> float:
    """Variance (rad²/s²) of the gyro white noise carried by the estimate of ω_B.

    Biased model: ω = gyro − bg at the last sample, σ_g²/h. Paper model: ω follows the stencil's
    anchor value, ``STENCIL_RATE_VARIANCE`` σ_g²/h. It is fresh at every IMU sample, so it does
    not accumulate: in the paper model ``navigation.ins.InsFilter`` adds it to the state's ω
    variance where ω̂ is compared with the world (vision updates, logged deviations) instead of
    letting it random-walk in P.
    """
    coef = 1.0 if layout.biased else STENCIL_RATE_VARIANCE
    return coef * noise.gyro_noise_density**2 / h_imu_s


# An IMU interval longer than this many sensor periods lacks samples of the sensor's own stream.
MISSING_SAMPLE_FACTOR = 1.5
# Longer intervals are dropouts, not a recording that keeps some samples: the sample says
# nothing about the motion there, so the fault guard's gap noise covers them
# (``navigation.fault_handling``), not a held sample's white noise.
MAX_HELD_INTERVAL_S = 0.5


def held_intervals(
    interval_s: F64, h_imu_s: float, factor: float = MISSING_SAMPLE_FACTOR
) -> NDArray[np.bool_]:
    """Which IMU intervals (N,) s stand for missing samples of the sensor's own stream: longer
    than ``factor`` sensor periods ``h_imu_s``, at most ``MAX_HELD_INTERVAL_S``."""
    D = np.asarray(interval_s, dtype=float)
    return (factor * h_imu_s < D) & (D <= MAX_HELD_INTERVAL_S)


# Fewer regular triples than this leave a stream's chord residual unmeasured.
MIN_CHORD_TRIPLES = 20


def chord_residual_variance(
    t_s: F64, x: F64, h_imu_s: float, factor: float = MISSING_SAMPLE_FACTOR, missing: int = 1
) -> float:
    """Per-axis variance of what the chord across ``missing`` samples misses, over the windows
    of ``x`` (N, 3) at ``t_s`` (N,) s whose ``missing + 1`` intervals are all regular (at most
    ``factor`` periods ``h_imu_s``); NaN when fewer than ``MIN_CHORD_TRIPLES`` windows.

    For a window x_0 … x_{m+1} the residual is ``S = Σ_{j=1..m} x_j − (m/2)(x_0 + x_{m+1})``:
    the trapezoid across a hole of m samples misses ``h S`` of the integral. One missing sample
    gives each sample's departure from its neighbours' mean, ``x_k − (x_{k−1} + x_{k+1})/2``.
    White noise gives σ²/h (m + m²/2); a vibrating airframe far more, and growing faster than m
    (its vibration is signal between samples that no noise density describes, and coherent
    over several: a probe's real EuRoC holes of 10 cost 4x m times the one-sample price).
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(x, dtype=float)
    m = int(missing)
    if m < 1:
        raise ValueError(f"missing must be >= 1, got {missing}")
    n_win = len(t) - m - 1
    if n_win < 1:
        return float("nan")
    irregular = np.concatenate([[0], np.cumsum(np.diff(t) > factor * h_imu_s)])
    ok = irregular[m + 1:] - irregular[: n_win] == 0  # no irregular interval in the window
    if int(np.count_nonzero(ok)) < MIN_CHORD_TRIPLES:
        return float("nan")
    c = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    inner = c[m + 1: m + 1 + n_win] - c[1: 1 + n_win]  # x_1 + … + x_m of each window
    e = inner - 0.5 * m * (v[:n_win] + v[m + 1: m + 1 + n_win])
    e = e[ok]
    return float(np.mean(e * e))


def white_noise_duration_s(
    dt_s: F64,
    interval_s: F64,
    h_imu_s: float,
    factor: float = MISSING_SAMPLE_FACTOR,
    hole_s: F64 | None = None,
) -> float:
    """Duration (s) that sets the white-noise terms of ``process_noise`` over steps ``dt_s``.

    A step inside a regular stream (its IMU interval ``interval_s`` at most ``factor`` sensor
    periods ``h_imu_s``) counts its own length. A recording may keep only some samples of a
    sensor (KITTI raw: 100 Hz OXTS records 10-250 ms apart); a kept sample then stands for the
    whole interval D it starts, so its white noise (variance σ²/h) enters the increment as
    σ² D² / h instead of σ² D: the step counts ``dt · D / h``. Equal to ``sum(dt_s)`` on a
    regular stream, and on dropouts longer than ``MAX_HELD_INTERVAL_S``. ``dt_s`` (N,) step
    lengths, ``interval_s`` (N,) the IMU interval holding each. ``hole_s`` (N,) s: the
    white-noise duration the missing samples of each step's interval are worth together,
    ``h² var(S) / σ²`` with the stream's chord residual across them ``var(S)``
    (``chord_residual_variance``; None: the white noise alone); a held step counts at least
    its length plus its share of its interval's.
    """
    dt = np.asarray(dt_s, dtype=float)
    D = np.asarray(interval_s, dtype=float)
    held = held_intervals(D, h_imu_s, factor)
    per_step = dt * D / h_imu_s
    if hole_s is not None:
        # A hole in a stream that keeps every sample: its missing samples are worth ``hole_s``
        # of white noise (the chord residual across them), shared among the steps of its
        # interval by length.
        worth = np.asarray(hole_s, dtype=float)
        per_step = np.maximum(per_step, dt + dt / np.maximum(D, 1e-12) * worth)
    return float(np.sum(np.where(held, per_step, dt)))


def process_noise(
    layout: StateLayout,
    noise: ImuNoise,
    duration_s: float,
    h_imu_s: float,
    white_duration_s: float | None = None,
    accel_white_duration_s: float | None = None,
) -> F64:
    """Tangent-space process noise ``Q`` (ndx, ndx) accumulated over ``duration_s``.

    ``white_duration_s`` (default ``duration_s``): the white-noise terms' duration, longer where
    the recording lacks samples (``white_noise_duration_s``); random walks use ``duration_s``.
    ``accel_white_duration_s`` (default ``white_duration_s``): the accelerometer's, where it
    differs from the gyro's.

    Accelerometer white noise integrates into v and p with the exact double-integrator
    covariance (T, T²/2, T³/3); gyro white noise gives the attitude random walk σ² T. In the
    biased model ω is re-read from the gyro at each sample, so its noise is the white sample
    variance σ²/h (not accumulated); in the paper model ω random-walks with the gyro bias drift
    here, and its white part (``omega_white_variance``, not accumulated either: ω re-anchors to
    the latest gyro samples) is handled by ``navigation.ins.InsFilter`` (``omega_white``).
    """
    T = duration_s
    Qm = np.zeros((layout.ndx, layout.ndx))
    # Missing samples scale the white terms: variance grows by white_duration / duration.
    r = 1.0 if white_duration_s is None or T <= 0 else white_duration_s / T
    ra = r if accel_white_duration_s is None or T <= 0 else accel_white_duration_s / T
    qa = noise.accel_noise_density**2 * ra
    eye = np.eye(3)
    Qm[DP, DP] = qa * T**3 / 3.0 * eye
    Qm[DP, DV] = Qm[DV, DP] = qa * T**2 / 2.0 * eye
    Qm[DV, DV] = qa * T * eye
    Qm[DTH, DTH] = noise.gyro_noise_density**2 * r * T * eye
    if layout.biased:
        Qm[DW, DW] = noise.gyro_noise_density**2 / h_imu_s * eye
        Qm[DBG, DBG] = noise.gyro_random_walk**2 * T * eye
        Qm[DBA, DBA] = noise.accel_random_walk**2 * T * eye
    else:
        Qm[DW, DW] = noise.gyro_random_walk**2 * T * eye
    return Qm
