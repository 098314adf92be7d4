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

Options come from ``RunOptions.method_options`` (keys of :class:`VisionOptions`). The pixel
updater lives in ``vision_pixels``, its noise model in ``vision_noise``, the IMU increments and
the front end's motion prior in ``vision_motion``; this module re-exports ``PixelUpdater``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.errors import ConfigError, DatasetError
from svains.filter.ukf import UpdateStats
from svains.frontend.types import StereoTracks
from svains.models.vision_clone import predict_egomotion_clone
from svains.models.vision_common import ROTATION_MODELS, ImuIncrement
from svains.models.vision_lc import egomotion_measurement, predict_egomotion_lc
from svains.navigation.base import FrameContext, MeasurementBlock
from svains.navigation.tracks import TrackOptions
from svains.navigation.vision_clones import CloneWindow, next_reference_ns
from svains.navigation.vision_pixels import (
    PixelUpdater,
    VisionCounters,
    apply_blocks,
    imu_and_prior,
    tracks_with_prior,
)
from svains.navigation.vision_sources import SourceName, make_source

__all__ = ["LcUpdater", "PixelUpdater", "VisionOptions", "make_vision_updater", "tune_run_options"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

log = logging.getLogger(__name__)

# Variance factor on the front end's egomotion covariance for ``lc``: a measured allowance for
# what the lc model leaves out, no longer a repair of the covariance. ``Egomotion.cov`` now
# propagates all four pixels (``svains.frontend.egomotion_cov``): its NEES is 6.2-6.7 on the
# rendered village images and 4.3-7.1 in Monte Carlo; on features0 (0.5 px) it is 18-29 (12 s,
# seeds 0, 3, 5), because the RANSAC refinement stops before its inlier selection settles. Yet
# lc is most accurate with far more than that (ATE [m] by factor, vo/lc only, 2026-11):
#   factor                            1      4      8     16     30     64    128    512
#   village 60 s x 10 seeds (mean)  1.24   0.92   0.77   0.66  ~0.62   0.60   0.57   0.49
#   EuRoC V1_01 + synthetic 5 Hz    1.09     -    0.21   0.17   0.09   0.10   0.12   0.17
# (village factor 30 interpolated: 32 gave 0.62). Likely cause: the lc model treats each
# egomotion as independent of the state error at k-1 (no clone). 30 is the best on EuRoC and
# close on the village (whose optimum, ~512, is worse on EuRoC).
LC_COV_SCALE = 30.0

# Vision motion models: the state-at-k ones of ``models.vision_common`` and ``clone`` (the pose
# at k-1 cloned into the state, ``navigation.vision_clones``; exact relative motion).
MOTION_MODELS = (*ROTATION_MODELS, "clone")


@dataclass(frozen=True)
class VisionOptions:
    """Vision-update settings (all from ``RunOptions.method_options``).

    ``pixel_noise_std`` px (None: the features0 value, 1 px for images) times
    ``pixel_noise_scale`` (None: ``noise_scale()``, 1 with clones, 2 for the approximate motion
    models); ``feature_gate_probability`` per-feature chi-square(4) gate (None: off);
    ``max_features`` per frame (evenly subsampled; None: all); ``rotation`` is the motion
    model between frames: "clone" (default: the pose at k-1 cloned into the state, exact
    relative motion, ``navigation.vision_clones``), "linear" (paper eq. 18), "exp" or "imu"
    (relative motion from the IMU samples between the frames: ``models.vision_imu``);
    ``single_use_pixels`` (clones) lets each feature pixel enter one update only (a feature
    fused at k-1 is not triangulated again at k); ``min_disparity_px`` (None:
    ``min_disparity()``) drops features whose disparity one frame earlier is smaller;
    ``frame_stride`` uses every n-th stereo frame;
    ``lc_cov_scale`` multiplies the egomotion covariance (None: ``lc_scale()``, 30, measured
    for lc's accuracy, see ``LC_COV_SCALE``);
    ``lc_min_std`` (rad, m) floors its standard deviations; ``imu_noise`` adds the IMU
    increment's noise (``rotation="imu"``) to the pixel covariance as a feature-correlated
    term; ``frame_gyro_walk`` (``imu`` only, applied by ``tune_run_options``) instead lets
    the gyro-bias state absorb it, see there; ``motion_prior`` hands the image front end the
    camera motion the filter predicts between its frames (``vision_motion.MotionPrior``), with
    ``motion_prior_inflation`` (variance factor) and ``motion_prior_min_std`` (rad, m) floors
    (off by default: on the simulated village sets, whose gyro is noisy, ``3d`` with the prior
    was better on the 20 Hz bench set, 0.041 m against 0.045 m RMSE, see
    ``bench/bench_methods.py``, and worse on the 2 Hz demo flight, 0.358 m against 0.259 m).
    """

    source: SourceName = "auto"
    pixel_noise_std: float | None = None
    pixel_noise_scale: float | None = None
    feature_gate_probability: float | None = 0.999
    max_features: int | None = 120
    min_features: int = 3
    rotation: str = "clone"
    frame_stride: int = 1
    max_row_diff_px: float | None = 2.0
    lc_cov_scale: float | None = None
    lc_min_std: tuple[float, float] = (1e-4, 1e-3)
    imu_noise: bool = True
    frame_gyro_walk: bool = True
    single_use_pixels: bool = True
    min_disparity_px: float | None = None
    motion_prior: bool = False
    motion_prior_inflation: float = 4.0
    motion_prior_min_std: tuple[float, float] = (2e-3, 5e-3)

    @classmethod
    def from_mapping(cls, values: dict[str, Any] | None) -> VisionOptions:
        """Build from a plain dict; unknown keys raise ``ConfigError`` naming them."""
        values = dict(values or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ConfigError(f"unknown vision options {unknown}; known: {sorted(names)}")
        for key in ("lc_min_std", "motion_prior_min_std"):
            if key in values:
                values[key] = tuple(values[key])
        opts = cls(**values)
        if opts.rotation not in MOTION_MODELS:
            raise ConfigError(f"rotation must be one of {MOTION_MODELS}, got {opts.rotation!r}")
        return opts

    def noise_scale(self) -> float:
        """``pixel_noise_scale``, or its default: 1 with clones (the relative motion is exact),
        2 for the models that approximate it (measured, see ``bench/tc_noise_scan.py``)."""
        if self.pixel_noise_scale is not None:
            return float(self.pixel_noise_scale)
        return 1.0 if self.rotation == "clone" else 2.0

    def min_disparity(self, sigma_px: float, noise_known: bool = True) -> float:
        """``min_disparity_px``, or its default: 12 pixel-noise standard deviations with
        clones when the pixel noise is known (``noise_known``: recorded features or a given
        ``pixel_noise_std``), none otherwise (the image front end's 1 px is a placeholder) and
        for the other models (their measured settings).

        Far features bias a clone-based update twice: their triangulated depth is non-linear
        in a disparity a few σ from zero (the linearised pixel noise no longer holds), and only
        features in front of the camera (k-1 disparity > 0) can be used, a selection on the
        k-1 noise. Measured on the 60 s village (10 seeds, 0.5 px): without the gate the
        position NEES is 50-140 (3 dof), ATE 0.35-0.40 m (seeds 0-2); gated at 5 px on the k-2
        disparity (``PixelUpdater._near``), ATE 0.10 m, NEES 14.9 (9 dof); at 6 px (12 σ) the
        NEES of seeds 0-3 falls from 17.0/17.8/15.0/12.1 to 12.4/14.5/12.8/8.8. On KITTI raw
        (images, σ taken as 1 px) any gate costs accuracy: final error 1.43 % ungated, 1.64 %
        at 5 px, 1.72 % at 10 px, 1.82 % at 12 px (largest error in two 10 s GPS outages 1.04 m
        against 0.85 m ungated).
        """
        if self.min_disparity_px is not None:
            return float(self.min_disparity_px)
        return 12.0 * sigma_px if self.rotation == "clone" and noise_known else 0.0

    def lc_scale(self) -> float:
        """``lc_cov_scale``, or its default ``LC_COV_SCALE``, with clones too. The clone puts the
        egomotion's correlation with the state at k-1 in the model, but not the correlation
        between consecutive egomotions (both use the k-1 pixels) nor the front end's own
        overconfidence on features0 (raw NEES 18-29 for 6 dof). Measured with clones, factor 1
        against 30: village 60 s seeds 0-2, ATE 0.415/0.310/0.501 m against 0.404/0.282/0.271,
        NEES 88/84/42 against 8.1/6.7/7.2; KITTI raw GPS-denied, final error 1.93 % (62 of 179
        frames rejected by the gate) against 1.39 %."""
        if self.lc_cov_scale is not None:
            return float(self.lc_cov_scale)
        return LC_COV_SCALE


class LcUpdater:
    """``lc`` updater: the egomotion ``(Log R_Ck_Ckm1, p_Ck_Ckm1)`` as a 6-number measurement."""

    method = "lc"

    def __init__(self, ds: Dataset, options: VisionOptions) -> None:
        self.options = options
        track_opts = TrackOptions(max_row_diff_px=options.max_row_diff_px, egomotion=True)
        self.source = make_source(ds, options.source, track_opts, options.frame_stride)
        self.rig = self.source.rig
        self.counters = VisionCounters()
        self._imu, self._prior = imu_and_prior(ds, options, self.source)
        self._nis_per_dof: list[float] = []  # consistency check: should average ~1
        self.clones = CloneWindow() if options.rotation == "clone" else None

    def frame_times(self) -> I64:
        return self.source.frame_times()

    def measurement(self, tr: StereoTracks) -> tuple[F64, F64]:
        """``z`` (6,) (rotation vector rad, translation m) and its covariance (6, 6): the front
        end's covariance times ``lc_cov_scale``, standard deviations floored at ``lc_min_std``.
        ``tr.egomotion`` must not be None."""
        if tr.egomotion is None:
            raise DatasetError(f"tracks at t={tr.t_ns} ns carry no egomotion (lc needs one)")
        z, cov = egomotion_measurement(tr.egomotion)
        cov = cov * self.options.lc_scale()
        floor = np.repeat(np.square(self.options.lc_min_std), 3)
        return z, cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))

    def update(self, ctx: FrameContext) -> UpdateStats | None:
        """Fuse the egomotion of the frame at ``ctx.t_ns`` (None if the front end gave none)."""
        c = self.counters
        c.frames += 1
        tr, inc = tracks_with_prior(self.source, self._prior, ctx)
        if tr is None or tr.egomotion is None or tr.t_ns <= tr.t_prev_ns:
            c.frames_without_tracks += 1
            return None
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        z, cov = self.measurement(tr)
        h = self._model(ctx, tr, dt_s, inc)
        if h is None:  # no clone of the k-1 frame (e.g. the first frame)
            c.frames_without_tracks += 1
            return None
        block = MeasurementBlock(name="vision_lc", h=h, z=z, R=cov)
        stats = apply_blocks(ctx, [block, *ctx.extra])
        if stats.dof > 0 and np.isfinite(stats.nis):
            self._nis_per_dof.append(stats.nis / stats.dof)
        if stats.accepted:
            c.frames_fused += 1
            c.features_fused += int(tr.inlier.sum())
        else:
            c.frames_rejected += 1
        return stats

    def _model(
        self, ctx: FrameContext, tr: StereoTracks, dt_s: float, inc: ImuIncrement | None
    ) -> Callable[[F64], F64] | None:
        """``h(X) -> (S, 6)``: the egomotion from the clone of the k-1 frame (``clone``; None
        without one) or from the state at k."""
        rig, rot = self.rig, self.options.rotation
        if self.clones is not None:
            cols = self.clones.columns(ctx.ukf, tr.t_prev_ns)
            return None if cols is None else (lambda X: predict_egomotion_clone(X, cols, rig))
        if self._imu is None or rot != "imu":
            inc = None
        elif inc is None:  # no prior, or it spanned another interval
            inc = self._imu.between(ctx, tr.t_prev_ns, tr.t_ns)
        return lambda X: predict_egomotion_lc(X, dt_s, rig, rot, inc)

    def after_frame(self, ctx: FrameContext) -> None:
        """Once per frame, after ``update``: keep the clone the next frame needs."""
        if self.clones is not None:
            self.clones.after_frame(ctx.ukf, ctx.t_ns, next_reference_ns(self.source, ctx.t_ns))

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = self.counters.as_dict()
        nis = np.asarray(self._nis_per_dof)
        out.update(
            source=self.source.kind, lc_cov_scale=self.options.lc_scale(),
            frontend_status=dict(getattr(self.source, "status_counts", {})),
            nis_per_dof_mean=float(nis.mean()) if nis.size else None,
            nis_per_dof_median=float(np.median(nis)) if nis.size else None,
        )
        return out


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
    # The source test first: a run from images never parses features0.
    feats = ds.features if vopts.source in ("auto", "features") else None
    if feats is not None:
        times = feats.frame_times()
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
