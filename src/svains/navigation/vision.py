"""Vision updaters for the runner (``navigation.base.VisionUpdater``): ``tc``, ``3d`` and ``lc``.

At each stereo frame k (the runner has propagated the filter to t_k):

- ``tc``/``3d``: the inlier features tracked from k-1 give 4 pixels each (``[uL, vL, uR, vR]``),
  predicted from every sigma point by ``models.vision_tc``/``models.vision_3d``. Before the
  update each feature's innovation is tested alone (Mahalanobis distance with its 4x4 innovation
  covariance against the chi-square(4) quantile): failing features are dropped and counted. The
  remaining pixels form one ``MeasurementBlock`` stacked with ``ctx.extra`` (GPS/sonar/mag stamped
  at the same time when the runner's ``stack_with_vision`` is set: eqs. 27-29), fused in ONE update
  (``ctx.apply``). Otherwise the runner has already fused those sequentially.
- ``lc``: the front end's egomotion (rotation vector, translation) with its covariance is the
  measurement of the state-predicted camera motion (eqs. 30-33, ``models.vision_lc``).

Options come from ``RunOptions.method_options`` (keys of :class:`VisionOptions`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.errors import ConfigError, DatasetError
from svains.filter.ukf import UpdateStats
from svains.frontend.types import StereoTracks
from svains.models.state import BA, BG
from svains.models.vision_3d import predict_pixels_3d
from svains.models.vision_common import (
    ROTATION_MODELS,
    ImuIncrement,
    camera_motion,
    stack_pixels,
)
from svains.models.vision_imu import imu_increment
from svains.models.vision_lc import egomotion_measurement, predict_egomotion_lc
from svains.models.vision_tc import predict_pixels_tc
from svains.navigation.base import FrameContext, MeasurementBlock
from svains.navigation.tracks import TrackOptions
from svains.navigation.vision_noise import (
    analytic_noise,
    feature_gate,
    lowrank_whiten,
    whiten,
)
from svains.navigation.vision_sources import (
    FeatureTrackSource,
    ImageTrackSource,
    SourceName,
    make_source,
)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

log = logging.getLogger(__name__)

# Variance factor on the front end's egomotion covariance for ``lc``. Measured (village, 5 Hz,
# features0, 0.5 px): the NEES of the true egomotion error against ``Egomotion.cov`` averages
# 140-200 over 4 seeds instead of 6 (per axis 15-70x), and 100 in a Monte Carlo with exact
# geometry and Gaussian pixel noise, so the overconfidence is the estimator's (noisy k-1
# triangulation, far points), not the data's. Unscaled, the filter's gate rejects ~25% of the
# frames and the rest pull the state too hard (run NEES 65).
LC_COV_SCALE = 30.0


@dataclass(frozen=True)
class VisionOptions:
    """Vision-update settings (all from ``RunOptions.method_options``).

    ``pixel_noise_std`` px (None: the features0 value, 1 px for images) times
    ``pixel_noise_scale`` (triangulation at k-1 and the small-motion model add error the paper's
    pixel noise does not model); ``feature_gate_probability`` per-feature chi-square(4) gate (None:
    off); ``max_features`` per frame (evenly subsampled; None: all); ``rotation`` "linear" (paper
    eq. 18), "exp" or "imu" (relative motion from the IMU samples between the frames, beyond the
    paper: ``models.vision_imu``); ``frame_stride`` uses every n-th stereo frame;
    ``lc_cov_scale`` multiplies the egomotion covariance (default 30: the front end's
    Gauss-Newton covariance is ~30x too small in variance, see ``LC_COV_SCALE``);
    ``lc_min_std`` (rad, m) floors its standard deviations; ``imu_noise`` adds the IMU
    increment's noise (``rotation="imu"``) to the pixel covariance as a feature-correlated
    term; ``frame_gyro_walk`` (``imu`` only, applied by ``tune_run_options``) instead lets
    the gyro-bias state absorb it, see there.
    """

    source: SourceName = "auto"
    pixel_noise_std: float | None = None
    pixel_noise_scale: float = 2.0
    feature_gate_probability: float | None = 0.999
    max_features: int | None = 120
    min_features: int = 3
    rotation: str = "linear"
    frame_stride: int = 1
    max_row_diff_px: float | None = 2.0
    lc_cov_scale: float = LC_COV_SCALE
    lc_min_std: tuple[float, float] = (1e-4, 1e-3)
    imu_noise: bool = True
    frame_gyro_walk: bool = True

    @classmethod
    def from_mapping(cls, values: dict[str, Any] | None) -> VisionOptions:
        """Build from a plain dict; unknown keys raise ``ConfigError`` naming them."""
        values = dict(values or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ConfigError(f"unknown vision options {unknown}; known: {sorted(names)}")
        if "lc_min_std" in values:
            values["lc_min_std"] = tuple(values["lc_min_std"])
        opts = cls(**values)
        if opts.rotation not in ROTATION_MODELS:
            raise ConfigError(f"rotation must be one of {ROTATION_MODELS}, got {opts.rotation!r}")
        return opts


@dataclass
class VisionCounters:
    """Per-run counts of the vision updates (go into ``report.json`` under ``vision``)."""

    frames: int = 0
    frames_without_tracks: int = 0
    frames_fused: int = 0
    frames_rejected: int = 0
    features_fused: int = 0
    features_gated: int = 0
    features_invalid: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: int(getattr(self, f.name)) for f in fields(self)}


def _subsample(idx: I64, n_max: int | None) -> I64:
    """At most ``n_max`` of ``idx``, evenly spread (tracks are ordered by id, i.e. by age)."""
    if n_max is None or idx.size <= n_max:
        return idx
    return idx[np.linspace(0, idx.size - 1, n_max).round().astype(np.int64)]


class _CachedModel:
    """``h`` restricted to kept features, reusing the gate pass's predictions for the same X."""

    def __init__(self, h_sub: Any, X0: F64, Y0: F64) -> None:
        self._h = h_sub
        self._X0 = X0
        self._Y0 = Y0

    def __call__(self, X: F64) -> F64:
        if X.shape == self._X0.shape and np.array_equal(X, self._X0):
            return self._Y0
        return self._h(X)


class _ImuIncrements:
    """IMU samples for the ``rotation="imu"`` increments between frames (body frame)."""

    def __init__(self, ds: Dataset, options: VisionOptions) -> None:
        if ds.imu is None:
            raise ConfigError("rotation='imu' needs the data set's IMU")
        R_B_S = np.eye(3) if ds.imu_calib is None else ds.imu_calib.T_B_S[:3, :3]
        self.t_ns = np.asarray(ds.imu.t_ns, np.int64)
        self.gyro_B = np.asarray(ds.imu.gyro_B, float) @ R_B_S.T
        self.accel_B = np.asarray(ds.imu.accel_B, float) @ R_B_S.T
        self.g_W = np.asarray(ds.gravity_W, float)
        cal = ds.imu_calib
        self.noise: tuple[float, float] | None = (
            None if cal is None or not options.imu_noise
            else (cal.gyro_noise_density, cal.accel_noise_density)
        )

    def between(self, ctx: FrameContext, t0_ns: int, t1_ns: int) -> ImuIncrement:
        """Increment over [t0, t1] with the filter's mean biases removed."""
        x = ctx.ukf.x
        biased = ctx.layout.biased
        return imu_increment(
            self.t_ns, self.gyro_B, self.accel_B, t0_ns, t1_ns, self.g_W,
            x[BG] if biased else None, x[BA] if biased else None,
        )


class PixelUpdater:
    """``tc`` or ``3d`` updater: 4 pixels per inlier feature, see the module docstring."""

    def __init__(self, method: str, ds: Dataset, options: VisionOptions) -> None:
        if method not in ("tc", "3d"):
            raise ConfigError(f"pixel updater serves tc or 3d, got {method!r}")
        self.method = method
        self.options = options
        track_opts = TrackOptions(max_row_diff_px=options.max_row_diff_px)
        self.source: FeatureTrackSource | ImageTrackSource = make_source(
            ds, options.source, track_opts, options.frame_stride
        )
        self.rig = self.source.rig
        std = options.pixel_noise_std
        std = self.source.pixel_noise_std if std is None else std
        self.sigma_px = max(float(std), 0.05) * options.pixel_noise_scale
        self.counters = VisionCounters()
        self._imu = _ImuIncrements(ds, options) if options.rotation == "imu" else None
        self._imu_noise = None if self._imu is None else self._imu.noise

    def frame_times(self) -> I64:
        return self.source.frame_times()

    def _model(self, uvl0: F64, uvr0: F64, dt_s: float, inc: ImuIncrement | None) -> Any:
        """``h(X)`` from the k-1 pixels (M, 2): ``3d`` triangulates them (eq. 10), ``tc``
        transfers them (eq. 21)."""
        rot = self.options.rotation
        if self.method == "3d":
            p = self.rig.triangulate(uvl0, uvr0)
            return lambda X: predict_pixels_3d(X, p, dt_s, self.rig, rot, inc)
        return lambda X: predict_pixels_tc(X, uvl0, uvr0, dt_s, self.rig, rot, inc)

    def _increment(self, ctx: FrameContext, tr: StereoTracks) -> ImuIncrement | None:
        """IMU increment between the two frames (``rotation="imu"`` only), biases from the mean."""
        return None if self._imu is None else self._imu.between(ctx, tr.t_prev_ns, tr.t_ns)

    def update(self, ctx: FrameContext) -> UpdateStats | None:
        """Fuse the frame at ``ctx.t_ns`` (see the module docstring)."""
        c = self.counters
        c.frames += 1
        tr = self.source.tracks_at(ctx.t_ns)
        usable = (
            np.zeros(0, bool) if tr is None
            else tr.inlier & np.isfinite(tr.p_Ckm1_F).all(axis=1) & (tr.p_Ckm1_F[:, 2] > 0)
        )
        if tr is None or usable.sum() < self.options.min_features or tr.t_ns <= tr.t_prev_ns:
            c.frames_without_tracks += 1
            return None
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        idx = _subsample(np.flatnonzero(usable), self.options.max_features)
        z = stack_pixels(tr.uv_left[idx], tr.uv_right[idx])
        uvl0, uvr0 = tr.uv_left_prev[idx], tr.uv_right_prev[idx]
        inc = self._increment(ctx, tr)
        X, _ = ctx.ukf.sigma_points()
        Y = self._model(uvl0, uvr0, dt_s, inc)(X)
        # Per-feature 4x4 noise: pixel noise at k plus the k-1 pixel noise carried through
        # triangulation/transfer (dominant for far points), and in "imu" mode the IMU
        # increment's noise as a feature-correlated factor G (4M, 6). Closed form at the mean
        # state (``analytic_noise``; tests check it against finite differences of the model).
        R_c, r_c = camera_motion(ctx.ukf.x[None, :], dt_s, self.rig, self.options.rotation, inc)
        R_blocks, G = analytic_noise(
            R_c[0], r_c[0], uvl0, uvr0, self.rig, self.sigma_px, inc, dt_s, self._imu_noise
        )
        pts = ctx.ukf.points
        keep, finite = feature_gate(
            Y, pts.Wm, pts.Wc, z, R_blocks, self.options.feature_gate_probability, G
        )
        # Near-zero disparity makes the prediction hypersensitive to the k-1 pixels (|J| > 100):
        # such features carry no information and would make R_blocks numerically singular.
        sane = np.abs(R_blocks).max(axis=(1, 2)) < (100.0 * self.sigma_px) ** 2
        finite &= sane
        keep &= sane
        c.features_invalid += int((~finite).sum())
        c.features_gated += int((finite & ~keep).sum())
        if keep.sum() < self.options.min_features:
            c.frames_without_tracks += 1
            return None
        kept = np.flatnonzero(keep)
        rows = (4 * kept[:, None] + np.arange(4)).reshape(-1)
        # Whiten each feature's 4 numbers so the stacked noise is diagonal (the filter's fast
        # Woodbury path instead of a dense nz x nz Cholesky).
        W_inv = np.linalg.inv(np.linalg.cholesky(R_blocks[kept]))  # (K, 4, 4)
        h_kept = self._model(uvl0[kept], uvr0[kept], dt_s, inc)
        # The IMU term, common to all features, is whitened too: (I + Gw Gw^T)^-1/2 is
        # identity minus a rank-6 correction, so the stacked noise stays diagonal.
        Gw = None if G is None else whiten(G[rows].T, W_inv).T

        def white(Yr: F64) -> F64:
            return lowrank_whiten(whiten(Yr, W_inv), Gw)

        h = _CachedModel(lambda X_: white(h_kept(X_)), X, white(Y[:, rows]))
        block = MeasurementBlock(
            name=f"vision_{self.method}", h=h, z=white(z[rows][None, :])[0],
            R=np.ones(rows.size),
        )
        stats = _apply(ctx, [block, *ctx.extra])
        if stats.accepted:
            c.frames_fused += 1
            c.features_fused += int(keep.sum())
        else:
            c.frames_rejected += 1
        return stats

    def summary(self) -> dict[str, Any]:
        """Counters and settings for ``report.json``."""
        out: dict[str, Any] = self.counters.as_dict()
        out.update(source=self.source.kind, sigma_px=self.sigma_px, rotation=self.options.rotation)
        return out


class LcUpdater:
    """``lc`` updater: the egomotion ``(Log R_Ck_Ckm1, p_Ck_Ckm1)`` as a 6-number measurement."""

    method = "lc"

    def __init__(self, ds: Dataset, options: VisionOptions) -> None:
        self.options = options
        track_opts = TrackOptions(max_row_diff_px=options.max_row_diff_px, egomotion=True)
        self.source = make_source(ds, options.source, track_opts, options.frame_stride)
        self.rig = self.source.rig
        self.counters = VisionCounters()
        self._imu = _ImuIncrements(ds, options) if options.rotation == "imu" else None
        self._nis_per_dof: list[float] = []  # consistency check: should average ~1

    def frame_times(self) -> I64:
        return self.source.frame_times()

    def measurement(self, tr: StereoTracks) -> tuple[F64, F64]:
        """``z`` (6,) (rotation vector rad, translation m) and its covariance (6, 6): the front
        end's covariance times ``lc_cov_scale``, standard deviations floored at ``lc_min_std``.
        ``tr.egomotion`` must not be None."""
        if tr.egomotion is None:
            raise DatasetError(f"tracks at t={tr.t_ns} ns carry no egomotion (lc needs one)")
        z, cov = egomotion_measurement(tr.egomotion)
        cov = cov * self.options.lc_cov_scale
        floor = np.repeat(np.square(self.options.lc_min_std), 3)
        return z, cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))

    def update(self, ctx: FrameContext) -> UpdateStats | None:
        """Fuse the egomotion of the frame at ``ctx.t_ns`` (None if the front end gave none)."""
        c = self.counters
        c.frames += 1
        tr = self.source.tracks_at(ctx.t_ns)
        if tr is None or tr.egomotion is None or tr.t_ns <= tr.t_prev_ns:
            c.frames_without_tracks += 1
            return None
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        z, cov = self.measurement(tr)
        rig, rot = self.rig, self.options.rotation
        inc = None if self._imu is None else self._imu.between(ctx, tr.t_prev_ns, tr.t_ns)
        block = MeasurementBlock(
            name="vision_lc", h=lambda X: predict_egomotion_lc(X, dt_s, rig, rot, inc), z=z, R=cov
        )
        stats = _apply(ctx, [block, *ctx.extra])
        if stats.dof > 0 and np.isfinite(stats.nis):
            self._nis_per_dof.append(stats.nis / stats.dof)
        if stats.accepted:
            c.frames_fused += 1
            c.features_fused += int(tr.inlier.sum())
        else:
            c.frames_rejected += 1
        return stats

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = self.counters.as_dict()
        nis = np.asarray(self._nis_per_dof)
        out.update(
            source=self.source.kind, lc_cov_scale=self.options.lc_cov_scale,
            nis_per_dof_mean=float(nis.mean()) if nis.size else None,
            nis_per_dof_median=float(np.median(nis)) if nis.size else None,
        )
        return out


def _apply(ctx: FrameContext, blocks: list[MeasurementBlock]) -> UpdateStats:
    """One stacked update through the runner (``ctx.apply``) or the filter directly."""
    if ctx.apply is not None:
        return ctx.apply(blocks)
    if len(blocks) != 1:
        raise ConfigError("stacked updates need the runner's ctx.apply")
    b = blocks[0]
    return ctx.ukf.update(b.h, b.z, b.R, ctx.gate_probability, b.residual, b.name)


def tune_run_options(ds: Dataset, method: str, options: Any) -> Any:
    """``RunOptions`` for ``method`` with the ``rotation="imu"`` noise treatment (beyond the paper).

    The gyro's white noise integrated between two frames (``σ_g² Δt``) is common to all features.
    Treated as measurement noise (``imu_noise``) it hides the relative rotation the features see;
    modelled instead as a gyro-bias random walk of density ``σ_g / Δt_frame`` it becomes a state
    the features observe, and the attitude follows the vision (measured: GPS-denied village
    5 Hz final error 2.0% -> 0.9% of the path, see the report). Other methods/options: unchanged.
    """
    mo = dict(getattr(options, "method_options", None) or {})
    vopts = VisionOptions.from_mapping(mo)
    cal = ds.imu_calib
    if method not in ("3d", "tc", "lc") or vopts.rotation != "imu" or not vopts.frame_gyro_walk:
        return options
    if cal is None:
        return options
    if ds.features is not None and vopts.source in ("auto", "features"):
        times = ds.features.frame_times()
    elif ds.left is not None:
        times = np.asarray(ds.left.t_ns, np.int64)
    else:
        return options
    times = times[:: max(1, vopts.frame_stride)]
    if len(times) < 2:
        return options
    period_s = float(np.median(np.diff(times))) * 1e-9
    base = options.noise.gyro_random_walk
    walk = max(cal.gyro_random_walk if base is None else base, cal.gyro_noise_density / period_s)
    log.info("%s: gyro-bias random walk %.3g rad/s/sqrt(s) for %.3f s frames", method, walk,
             period_s)
    return replace(options, noise=replace(options.noise, gyro_random_walk=walk),
                   method_options={**mo, "imu_noise": False})


def make_vision_updater(method: str, ds: Dataset, options: Any) -> PixelUpdater | LcUpdater:
    """Updater for ``method`` in {tc, 3d, lc}; ``options`` is a ``RunOptions`` (or None)."""
    mo = getattr(options, "method_options", None) if options is not None else None
    vopts = VisionOptions.from_mapping(mo)
    if method == "lc":
        return LcUpdater(ds, vopts)
    return PixelUpdater(method, ds, vopts)
