"""The inertial navigation filter: IMU propagation to any time, non-vision measurement updates.

``InsFilter`` owns a ``UKF`` on the navigation manifold and reads the IMU from an ``ImuHistory``
that grows as samples arrive. ``propagate_to(t_ns)`` integrates the IMU exactly to ``t_ns`` (the
IMU input at a time between two samples is linearly interpolated), in chunks of at most
``FilterOptions.max_predict_steps`` IMU steps per sigma-point draw.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError, FilterError
from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.filter.ukf import UKF, UpdateStats
from svains.models.gps import correlated_position_scale, gps_position, gps_position_velocity
from svains.models.imu import (
    MIN_CHORD_TRIPLES,
    ImuChunk,
    ImuModel,
    ImuNoise,
    chord_residual_variance,
    held_intervals,
    omega_white_variance,
    process_noise,
    white_noise_duration_s,
)
from svains.models.magnetometer import magnetic_field
from svains.models.manifold import NavManifold
from svains.models.sonar import sonar_range
from svains.models.state import DW, StateLayout
from svains.models.state import W as W_SLICE
from svains.navigation.base import MeasurementBlock
from svains.navigation.imu_history import ImuHistory
from svains.navigation.init import InitialState
from svains.navigation.options import FilterOptions, NoiseOptions
from svains.sensors.types import GpsCalib, ImuCalib, MagCalib, Rig, SonarCalib

# IMU samples before a hole whose chord residual prices its missing samples (1.3 s at 200 Hz).
CHORD_WINDOW = 256

F64 = NDArray[np.float64]

# EuRoC ADIS16448 values, used when a data set has no IMU calibration.
_DEFAULT_NOISE = ImuNoise(1.6968e-4, 1.9393e-5, 2.0e-3, 3.0e-3)


def default_imu_calib() -> ImuCalib:
    """The IMU a rig without one is run with: mounted at the body, rate unknown, the default
    noise densities (EuRoC's ADIS16448, as the filter's ``imu_noise``)."""
    n = _DEFAULT_NOISE
    return ImuCalib(np.eye(4), 0.0, n.gyro_noise_density, n.gyro_random_walk,
                    n.accel_noise_density, n.accel_random_walk)  # fmt: skip


def imu_noise(c: ImuCalib | None, layout: StateLayout, options: NoiseOptions) -> ImuNoise:
    """Noise densities: the IMU calibration, overridden and scaled by ``options``."""
    base = (
        _DEFAULT_NOISE
        if c is None
        else ImuNoise(
            c.gyro_noise_density, c.gyro_random_walk, c.accel_noise_density, c.accel_random_walk
        )
    )

    def pick(override: float | None, value: float) -> float:
        return value if override is None else override

    accel_white = pick(options.accel_noise_density, base.accel_noise_density) * options.white_scale
    if not layout.biased:
        accel_white = float(np.hypot(accel_white, options.paper_extra_accel_density))
    return ImuNoise(
        pick(options.gyro_noise_density, base.gyro_noise_density) * options.white_scale,
        pick(options.gyro_random_walk, base.gyro_random_walk) * options.random_walk_scale,
        accel_white,
        pick(options.accel_random_walk, base.accel_random_walk) * options.random_walk_scale,
    )


def imu_sample_period(rig: Rig) -> float:
    """Period (s) that sets one IMU sample's white-noise variance ``σ²/h``: the sensor's own
    rate from its calibration (a sample averages the signal over its sensor period, whatever
    gaps the recording leaves: KITTI raw keeps 100 Hz OXTS records 10-250 ms apart); the
    nominal step ``rig.imu_period_s`` without one. Propagation and the accumulated process
    noise use each step's own length (``propagate_to``)."""
    if rig.imu is not None and rig.imu.rate_hz > 0:
        return 1.0 / float(rig.imu.rate_hz)
    return float(rig.imu_period_s)


class InsFilter:
    """UKF + IMU timeline; ``t_ns`` is the time of the current estimate ``ukf.x``, ``ukf.P``."""

    def __init__(
        self,
        history: ImuHistory,
        rig: Rig,
        layout: StateLayout,
        init: InitialState,
        filter_options: FilterOptions,
        noise_options: NoiseOptions,
    ) -> None:
        """``history`` must hold the sample at ``init.t_ns``; it may grow afterwards."""
        if filter_options.max_predict_steps < 1:
            raise ConfigError("max_predict_steps must be >= 1")
        T_B_S = np.eye(4) if rig.imu is None else rig.imu.T_B_S
        self.layout = layout
        self.history = history
        self.options = filter_options
        if filter_options.propagation not in ("preintegrated", "exact"):
            raise ConfigError(f"unknown propagation {filter_options.propagation!r}")
        self.model = ImuModel(
            layout,
            np.asarray(rig.gravity_W, dtype=float),
            T_B_S[:3, 3],
            filter_options.propagation == "preintegrated",
        )
        self.noise = imu_noise(rig.imu, layout, noise_options)
        self._h_imu = imu_sample_period(rig)
        points = MerweScaledSigmaPoints(
            layout.ndx, filter_options.alpha, filter_options.beta, filter_options.kappa
        )
        # Paper model: ω̂ follows the stencil's anchor on the latest gyro samples, so its error is
        # a persistent part (the state's P) plus the white noise of those samples, variance
        # ``omega_white`` (``models.imu.omega_white_variance``), fresh at every IMU sample: not a
        # random walk in P (it does not accumulate) and invisible to GPS/mag/sonar. Vision
        # updates (their rotation models use ω) see it: in P while the updater gates features
        # (``add_omega_white``), as measurement noise in the update itself (``apply``). The
        # logged ω deviations include it (``tangent_std``). The initial ω is the
        # stencil-consistent gyro value (``init.initialise``), so no anchor noise persists.
        # The biased model re-reads ω from the gyro and needs none of this.
        self.omega_white = (
            0.0 if layout.biased else omega_white_variance(layout, self.noise, self._h_imu)
        )
        self._white_in_P = False
        self.ukf = UKF(NavManifold(layout), points, init.x, init.P)
        k = int(np.searchsorted(self.t_imu, init.t_ns))
        if k >= len(self.t_imu) or self.t_imu[k] != init.t_ns:
            raise ConfigError("the initial time must be an IMU sample time")
        self.t_ns = int(init.t_ns)
        # Absolute index (``history.dropped`` + local) of the next sample to integrate.
        self._k_next_abs = k + 1 + self.history.dropped
        self._u = (self.gyro_B[k], self.accel_B[k], self.alpha_B[k])
        self._q_cache: dict[int, F64] = {}
        self._chord_cache: dict[tuple[int, int], tuple[float, float]] = {}

    # The IMU received so far (views: they grow with the history).
    @property
    def t_imu(self) -> NDArray[np.int64]:
        return self.history.t_ns

    @property
    def gyro_B(self) -> F64:
        return self.history.gyro_B

    @property
    def accel_B(self) -> F64:
        return self.history.accel_B

    @property
    def alpha_B(self) -> F64:
        return self.history.alpha_B

    @property
    def t_end_ns(self) -> int:
        """Last IMU sample time: the filter cannot propagate beyond it."""
        return int(self.history.t_ns[-1])

    def _interp(self, t_ns: int) -> tuple[F64, F64, F64]:
        k = int(np.searchsorted(self.t_imu, t_ns))
        if self.t_imu[k] == t_ns:
            return self.gyro_B[k], self.accel_B[k], self.alpha_B[k]
        s = (t_ns - self.t_imu[k - 1]) / (self.t_imu[k] - self.t_imu[k - 1])
        return tuple(  # type: ignore[return-value]
            (1 - s) * a[k - 1] + s * a[k] for a in (self.gyro_B, self.accel_B, self.alpha_B)
        )

    def _noise(self, duration_ns: int) -> F64:
        Q = self._q_cache.get(duration_ns)
        if Q is None:
            Q = process_noise(self.layout, self.noise, duration_ns * 1e-9, self._h_imu)
            if len(self._q_cache) < 64:
                self._q_cache[duration_ns] = Q
        return Q

    def propagate_to(self, t_ns: int) -> None:
        """Predict the state at ``t_ns`` (>= current time, <= last IMU sample)."""
        t_ns = int(t_ns)
        if t_ns < self.t_ns:
            raise FilterError(f"cannot propagate backwards ({t_ns} < {self.t_ns})")
        if t_ns > self.t_end_ns:
            raise FilterError(f"{t_ns} ns is after the last IMU sample ({self.t_end_ns} ns)")
        if t_ns == self.t_ns:
            return
        k_end = int(np.searchsorted(self.t_imu, t_ns, side="right"))
        k_next = self._k_next_abs - self.history.dropped
        k_cur = k_next - 1
        if self.t_imu[k_cur] == self.t_ns and self.t_imu[k_end - 1] == t_ns:
            # Fast path: both ends are IMU samples, the nodes are slices (no copies).
            self._predict_nodes(
                self.t_imu[k_cur:k_end],
                self.gyro_B[k_cur:k_end],
                self.accel_B[k_cur:k_end],
                self.alpha_B[k_cur:k_end],
            )
            self.t_ns = t_ns
            self._k_next_abs = k_end + self.history.dropped
            self._u = (self.gyro_B[k_end - 1], self.accel_B[k_end - 1], self.alpha_B[k_end - 1])
            return
        ks = np.arange(k_next, k_end)
        times = [np.array([self.t_ns]), self.t_imu[ks]]
        u_end = None
        if len(ks) == 0 or self.t_imu[ks[-1]] != t_ns:
            u_end = self._interp(t_ns)
            times.append(np.array([t_ns]))
        t_nodes = np.concatenate(times)
        arrays = []
        for i, a in enumerate((self.gyro_B, self.accel_B, self.alpha_B)):
            parts = [self._u[i][None], a[ks]]
            if u_end is not None:
                parts.append(u_end[i][None])
            arrays.append(np.concatenate(parts))
        self._predict_nodes(t_nodes, *arrays)
        self.t_ns = t_ns
        self._k_next_abs = k_end + self.history.dropped
        self._u = (arrays[0][-1], arrays[1][-1], arrays[2][-1])

    def _predict_nodes(self, t_nodes: NDArray[np.int64], gyro: F64, accel: F64, alpha: F64) -> None:
        """UKF predictions over the nodes, at most ``max_predict_steps`` steps per draw."""
        step = self.options.max_predict_steps
        n_steps = len(t_nodes) - 1
        for j0 in range(0, n_steps, step):
            j1 = min(j0 + step, n_steps) + 1
            tt = t_nodes[j0:j1]
            chunk = ImuChunk(np.diff(tt) * 1e-9, gyro[j0:j1], accel[j0:j1], alpha[j0:j1])
            self.ukf.predict(self.model, chunk, 0.0, self._chunk_noise(tt))

    def _chunk_noise(self, tt: NDArray[np.int64]) -> F64:
        """Process noise over the nodes ``tt`` (int64 ns); white terms longer where the IMU
        interval holding a step lacks samples (``models.imu.white_noise_duration_s``)."""
        span_ns = int(tt[-1] - tt[0])
        t_imu = self.t_imu
        k = np.searchsorted(t_imu, tt[1:])  # the IMU sample ending each step's interval
        interval_ns = t_imu[k] - t_imu[k - 1]
        held = held_intervals(interval_ns * 1e-9, self._h_imu)
        if not np.any(held):
            return self._noise(span_ns)
        dt_s, interval_s = np.diff(tt) * 1e-9, interval_ns * 1e-9
        missing = np.maximum(np.rint(interval_s / self._h_imu).astype(np.int64) - 1, 1)
        gyro_s, accel_s = np.zeros(dt_s.size), np.zeros(dt_s.size)
        first = int(k[np.argmax(held)])
        for m in np.unique(missing[held]):
            at = held & (missing == m)
            gyro_s[at], accel_s[at] = self._hole_s(first, int(m))
        white_g = white_noise_duration_s(dt_s, interval_s, self._h_imu, hole_s=gyro_s)
        white_a = white_noise_duration_s(dt_s, interval_s, self._h_imu, hole_s=accel_s)
        return process_noise(
            self.layout, self.noise, span_ns * 1e-9, self._h_imu, white_g, white_a
        )

    def _hole_s(self, k: int, missing: int) -> tuple[float, float]:
        """White-noise durations (s), gyro and accelerometer, that ``missing`` samples missing
        before IMU sample ``k`` are worth together: the chord residual across as many samples
        in the ``CHORD_WINDOW`` samples before it (``models.imu.chord_residual_variance``) over
        the noise density; 0 where unmeasured. A hole too long for the window (or its regular
        runs) takes the longest measured one's price times the squared ratio (the chord's
        error through its two end samples grows so)."""
        key = (k + self.history.dropped, missing)  # the hole's sample, absolute: asked again
        cached = self._chord_cache.get(key)  # by each chunk a frame or tick splits it into
        if cached is not None:
            return cached
        lo = max(0, k - CHORD_WINDOW)
        t_s = (self.t_imu[lo:k] - self.t_imu[lo]) * 1e-9
        h = self._h_imu
        # the longest hole the window measures (MIN_CHORD_TRIPLES regular runs of m + 2
        # samples): halved until it does, a window broken by earlier drops measuring shorter
        # ones only (a hole of 60 after three single drops was priced as white noise alone,
        # 0.001x its cost: a user's probe)
        m = min(missing, max(1, k - lo - 1 - MIN_CHORD_TRIPLES))
        out = []
        for x, density in (
            (self.gyro_B[lo:k], self.noise.gyro_noise_density),
            (self.accel_B[lo:k], self.noise.accel_noise_density),
        ):
            at = m
            got = chord_residual_variance(t_s, x, h, missing=at)
            while not np.isfinite(got) and at > 1:
                at //= 2
                got = chord_residual_variance(t_s, x, h, missing=at)
            ok = np.isfinite(got) and density > 0.0
            out.append((missing / at) ** 2 * h * h * got / density**2 if ok else 0.0)
        if len(self._chord_cache) > 64:
            self._chord_cache.clear()
        self._chord_cache[key] = (out[0], out[1])
        return out[0], out[1]

    def add_omega_white(self) -> None:
        """Paper model: add ω̂'s gyro white noise to P while a vision updater inspects the filter
        (its feature gates then see it); ``apply`` and ``remove_omega_white`` take it out again.
        """
        if self.omega_white <= 0.0 or self._white_in_P:
            return
        self._shift_omega_variance(self.omega_white)
        self._white_in_P = True

    def remove_omega_white(self) -> None:
        """Undo ``add_omega_white`` if no update consumed it (exact: P is unchanged since)."""
        if self._white_in_P:
            self._shift_omega_variance(-self.omega_white)
            self._white_in_P = False

    def _shift_omega_variance(self, d: float) -> None:
        P = self.ukf.P.copy()
        idx = np.arange(P.shape[0])[DW]
        P[idx, idx] += d
        self.ukf.P = P

    def _omega_white_D(self, h: Callable[[F64], F64], nz: int) -> F64:
        """``D`` (3, nz): ω̂'s white part through ``h`` (its measurement covariance is
        ``D^T D``), central differences at the mean for ω ± σ_white on each axis."""
        X = np.repeat(self.ukf.x[None, :], 6, axis=0)
        step = np.sqrt(self.omega_white)
        for i in range(3):
            X[2 * i, W_SLICE.start + i] += step
            X[2 * i + 1, W_SLICE.start + i] -= step
        Y = np.reshape(h(X), (6, nz))
        return 0.5 * (Y[0::2] - Y[1::2])

    def tangent_std(self) -> F64:
        """Standard deviations (ndx,) of the navigation error, ω's white part included."""
        var = np.diag(self.ukf.P)[: self.layout.ndx].copy()  # pose clones excluded
        var[DW] += self.omega_white
        return np.sqrt(var)

    # ---- measurement blocks -------------------------------------------------------------
    def gps_block(
        self, cal: GpsCalib, p_W_G: F64, v_W_G: F64 | None, use_velocity: bool = True,
        spacing_s: float | None = None,
    ) -> MeasurementBlock:
        """Antenna position (and velocity, when given and ``use_velocity``), eqs. 4-5; the
        position's variance scaled for a noise correlated over ``cal.position_correlation_s``
        with the previous fix ``spacing_s`` (s) before (``correlated_position_scale``)."""
        var_p = cal.position_noise_std**2 * correlated_position_scale(
            cal.position_correlation_s, spacing_s)
        if use_velocity and v_W_G is not None:
            z = np.concatenate([p_W_G, v_W_G])
            R = np.r_[np.full(3, var_p), np.full(3, cal.velocity_noise_std**2)]
            return MeasurementBlock("gps", partial(gps_position_velocity, p_B_G=cal.p_B_G), z, R)
        return MeasurementBlock("gps", partial(gps_position, p_B_G=cal.p_B_G), p_W_G,
                                np.full(3, var_p))

    def mag_block(self, cal: MagCalib, m_S: F64) -> MeasurementBlock:
        """Magnetic field in the sensor frame (Gauss), eqs. 8-9."""
        h = partial(magnetic_field, m_W=cal.m_W, R_B_S=cal.T_B_S[:3, :3])
        return MeasurementBlock("mag", h, m_S, np.full(3, cal.noise_std**2))

    def sonar_block(self, cal: SonarCalib, range_m: float) -> MeasurementBlock:
        """Range to flat ground along the sonar's +z (m), eqs. 6-7."""
        h = partial(
            sonar_range, T_B_S=cal.T_B_S, g_W=self.model.g_W, ground_height=cal.ground_height
        )
        return MeasurementBlock("sonar", h, np.array([range_m]), np.array([cal.noise_std**2]))

    def apply(
        self, blocks: Sequence[MeasurementBlock], gate_probability: float | None = None,
        iterations: int = 1, max_nis_per_dof: float | None = None,
    ) -> UpdateStats:
        """One UKF update with the blocks stacked (one gate on the stacked innovation),
        linearised ``iterations`` times (``UKF.update``, also for ``max_nis_per_dof``)."""
        if len(blocks) == 0:
            raise ConfigError("apply() needs at least one measurement block")
        if len(blocks) == 1:
            b = blocks[0]
            h, z, R, tail = b.h, b.z, b.R, (b.residual, b.name)
        else:
            (h, z, R), tail = stack_blocks(blocks), _stacked_tail(blocks)
        D = None
        if self._white_in_P:
            # Paper model, vision update: ω̂'s white gyro noise is fresh at every sample, so it
            # is measurement noise of this update (through h, rank 3: ``D^T D``), not a state
            # error to correct (correcting it would leave a persistent ω offset integrating into
            # the attitude).
            self.remove_omega_white()
            D = self._omega_white_D(h, np.size(z))
        return self.ukf.update(h, z, R, gate_probability, *tail, R_low_rank=D,
                               iterations=iterations, max_nis_per_dof=max_nis_per_dof)  # fmt: skip


def stack_blocks(blocks: Sequence[MeasurementBlock]) -> tuple:
    """``(h, z, R)`` of the stacked measurement (R diagonal when every block's is)."""
    sizes = [b.z.size for b in blocks]
    edges = np.cumsum([0, *sizes])
    z = np.concatenate([np.ravel(b.z) for b in blocks])

    def h(X: F64) -> F64:
        return np.concatenate([np.reshape(b.h(X), (X.shape[0], -1)) for b in blocks], axis=1)

    if all(np.ndim(b.R) == 1 for b in blocks):
        R = np.concatenate([b.R for b in blocks])
    else:
        R = np.zeros((edges[-1], edges[-1]))
        for b, a, e in zip(blocks, edges[:-1], edges[1:], strict=True):
            R[a:e, a:e] = np.diag(b.R) if np.ndim(b.R) == 1 else b.R
    return h, z, R


def _stacked_tail(blocks: Sequence[MeasurementBlock]) -> tuple:
    """``(residual, name)`` of the stacked measurement."""
    name = "+".join(b.name for b in blocks)
    if all(b.residual is None for b in blocks):
        return None, name
    edges = np.cumsum([0, *[b.z.size for b in blocks]])

    def residual(a: F64, b_: F64) -> F64:
        out = a - b_
        for blk, s, e in zip(blocks, edges[:-1], edges[1:], strict=True):
            if blk.residual is not None:
                out[..., s:e] = blk.residual(a[..., s:e], b_[..., s:e])
        return out

    return residual, name
