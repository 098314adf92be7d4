"""The ``tc``/``3d`` vision updater: 4 pixels per inlier feature tracked from frame k-1.

See ``navigation.vision`` (module docstring) for the per-frame procedure; this module holds the
updater, its counters and the helpers it shares with ``lc`` (tracks with the front end's motion
prior, the stacked update).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError
from svains.filter.noise_correlation import NoiseCorrelation
from svains.filter.ukf import UpdateStats, chi2_gate
from svains.frontend.types import Egomotion, StereoTracks
from svains.models.vision_3d import move_points, pixels_from_motion
from svains.models.vision_clone import clone_camera_motion, predict_egomotion_clone
from svains.models.vision_common import ImuIncrement, camera_motion, project_stereo, stack_pixels
from svains.models.vision_tc import pixels_tc_from_motion
from svains.navigation import vision_correlated
from svains.navigation.base import FrameContext, MeasurementBlock, find_ids
from svains.navigation.fault_handling import scale_motion_covariance
from svains.navigation.imu_history import ImuHistory
from svains.navigation.relocalise import Relocaliser
from svains.navigation.vision_checks import applied_offset_s, vision_checks
from svains.navigation.vision_clones import clone_window, next_reference_ns
from svains.navigation.vision_egomotion import egomotion_block, tracks_egomotion
from svains.navigation.vision_motion import (
    CachedModel,
    ImuIncrements,
    MotionPrior,
    MotionPriorOptions,
)
from svains.navigation.vision_noise import (
    Whitening,
    analytic_noise,
    feature_gate,
    previous_pixel_bias,
    whiten_chol,
)
from svains.navigation.vision_sources import (
    FeatureFrames,
    ImageFrames,
    pixel_std_px,
    stereo_check_summary,
)
from svains.navigation.vision_two_view import TwoViewFeatures
from svains.sensors.types import Rig

if TYPE_CHECKING:
    from svains.navigation.options import VisionOptions

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
MotionFn = Callable[[F64], tuple[F64, F64]]

# ``PixelUpdater._near``: the k-1 disparity threshold of a feature with no k-2 pixels, in units
# of ``min_disparity_px`` (2 x 12 σ: 12 px at 0.5 px noise).
NEW_FEATURE_DISPARITY_FACTOR = 2.0

# ``vision.shared_pixels``: the variance factor of a pixel that enters two frame pairs (as the k
# pixel of one, the k-1 pixel of the next). Two updates at twice the variance carry the pixel's
# information once in total: the two pairs' errors are correlated through it, which the filter,
# fusing one pair at a time, cannot model; halving each pair's weight keeps the sum of what is
# fused at or below the truth (an information split, as covariance intersection does for
# unknown correlation with equal weights). Measured 2026-12-05 (EuRoC V1_01 synthetic 5 Hz,
# every frame, 300 features): NEES 5.1 for 9 dof.
SHARED_PIXEL_VARIANCE = 2.0


@dataclass
class VisionCounters:
    """Per-run counts of the vision updates (go into ``report.json`` under ``vision``)."""

    frames: int = 0
    frames_without_tracks: int = 0
    frames_fused: int = 0
    frames_rejected: int = 0
    frames_gated: int = 0  # of the rejected: refused by the frame test (too few pass)
    features_fused: int = 0
    features_gated: int = 0
    features_invalid: int = 0
    frames_bad_covariance: int = 0  # lc: the egomotion's covariance was not positive definite
    frames_egomotion: int = 0  # tc/3d: of the fused, through the frame's egomotion (fallback)
    frames_failed_numerics: int = 0  # skipped: the update raised a numerical error
    frames_inflated: int = 0  # of the fused egomotions (lc, tc/3d fallback): inflated
    # two-view: frames whose egomotion was computed to linearise at (the mean fitted poorly)
    frames_linearised_at_egomotion: int = 0
    # correlated pixels: features whose k-1 pixels' correlation was taken out, and frames where
    # it did not fit the prior (fused without those features' correlation)
    features_correlated: int = 0
    frames_correlation_dropped: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: int(getattr(self, f.name)) for f in fields(self)}


def _member(ids: I64, sorted_ids: I64) -> NDArray[np.bool_]:
    """``np.isin(ids, sorted_ids)`` for ascending ``sorted_ids`` (a binary search: several times
    cheaper than ``isin`` at a few hundred tracks)."""
    if sorted_ids.size == 0:
        return np.zeros(ids.shape, bool)
    pos = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.size - 1)
    return sorted_ids[pos] == ids


def _debiased(h: Callable[[F64], F64], bias: F64) -> Callable[[F64], F64]:
    """The measurement function ``h`` (sigma points -> (S, 4K) px) minus ``bias`` (4K,) px."""
    return lambda X: h(X) - bias


def _subsample(idx: I64, n_max: int | None) -> I64:
    """At most ``n_max`` of ``idx``, evenly spread (tracks are ordered by id, i.e. by age)."""
    if n_max is None or idx.size <= n_max:
        return idx
    return idx[np.linspace(0, idx.size - 1, n_max).round().astype(np.int64)]


@dataclass(frozen=True)
class _Features:
    """One frame's candidate features: the sigma points' predictions ``Y`` (S, dM), ``z``
    (dM,), per-feature noise ``R_blocks`` (M, d, d), the IMU-increment factor ``G`` (dM, 6) or
    None, ``keep``/``finite``/``nis`` (M,) from the gate, ``model(kept)``: ``h`` of the kept
    features for any sigma points, and (two-view) the null-space bases ``N`` (M, 8, 5)."""

    Y: F64
    z: F64
    R_blocks: F64
    G: F64 | None
    keep: NDArray[np.bool_]
    finite: NDArray[np.bool_]
    nis: F64
    model: Callable[[I64], Callable[[F64], F64]]
    N: F64 | None = None


class PixelUpdater:
    """``tc`` or ``3d`` updater: 4 pixels per inlier feature, see the module docstring."""

    def __init__(
        self, method: str, options: VisionOptions, source: FeatureFrames | ImageFrames,
        history: ImuHistory | None, rig: Rig,
    ) -> None:
        """``source`` gives the tracks; ``history`` the IMU (``rotation="imu"``, motion prior)."""
        if method not in ("tc", "3d"):
            raise ConfigError(f"pixel updater serves tc or 3d, got {method!r}")
        self.method = method
        self.options = options
        self.source = source
        self.rig = self.source.rig
        self._pixel_std_px = pixel_std_px(options.pixel_noise_std, source)  # unscaled
        self.sigma_px = self._pixel_std_px * options.noise_scale()
        self.clones = clone_window(options, applied_offset_s(rig), history, rig.gravity_W)
        self.checks = vision_checks(history, self.rig, rig)  # mount, stamps, baseline
        known = options.pixel_noise_std is not None or self.source.kind == "features"
        self.shared = self.clones is not None and options.shared_pixels
        # Pixels in both frame pairs with the correlation between the pairs followed
        # (``correlated_pixels``, ``vision_correlated``): where the pixel noise is known, as
        # the correlation is in its units.
        self.correlated = self.clones is not None and options.correlated_pixels and known
        self._correlation: NoiseCorrelation | None = None
        self._min_disparity_px = options.min_disparity(self.sigma_px, known, self.shared)
        # The k-1 pixel noise biases the prediction (``vision_noise.previous_pixel_bias``); the
        # correction needs the true noise, so it is made only when that is known.
        # So is the two-view misfit test (``vision_two_view.WIDE_MISFIT``), which reads residuals
        # in units of that noise: the egomotion is offered as a linearisation point only where
        # it is known (on rendered keyframes from images, 1 px assumed, it took V2_02 seed 2
        # from 0.366 to 0.996 m).
        self._noise_known = known
        # The last tracks' egomotion (``_egomotion_of``): a frame may need it twice. The flag:
        # whether its covariance was computed (a linearisation point needs the motion only).
        self._egomotion_memo: tuple[StereoTracks, Egomotion | None, bool] | None = None
        self.last_tracks: StereoTracks | None = None  # the last frame's (``camera_continuity``)
        self._fused: tuple[int, I64] | None = None  # (frame time, track ids) of the last update
        # Track ids and disparities (px) at the k-1 frame of the last tracks (``_near``).
        self._disparity_before: tuple[I64, F64] = (np.zeros(0, np.int64), np.zeros(0))
        self._disparity_t_ns: int | None = None
        self.counters = VisionCounters()
        self._imu, self._prior = imu_and_prior(history, rig, options, self.source)
        self._imu_noise = (
            None if options.rotation != "imu" or self._imu is None else self._imu.noise
        )
        # In a rectified pair tc's transfer and 3d's triangulation predict the same k pixels
        # from the same rigid motion of the k-1 stereo point, so the two-view update (the point
        # marginalised over both frames, ``navigation.vision_two_view``) stands for either. It
        # fuses the k-1 pixels themselves: the clone of the k-1 frame with shared pixels
        # (each pair at twice the variance) or single-use ones keeps them from being counted
        # twice.
        self.two_view = options.two_view or self.shared
        self._two_view_in_gaps = self.clones is not None and (
            options.single_use_pixels or self.shared or self.correlated)
        # One pixel's noise in the two-view update (px): split between the pairs it enters.
        self._two_view_sigma_px = self.sigma_px * (
            float(np.sqrt(SHARED_PIXEL_VARIANCE)) if self.shared else 1.0)
        # Keyframes for a frame that loses its link (``navigation.relocalise``).
        self.relocaliser = (
            Relocaliser(options, self.clones, source, self.rig)
            if options.relocalise and self.clones is not None and self._two_view_in_gaps
            else None
        )  # fmt: skip
        self._fused_before = 0
        # The instruments of the paper's model (``_instrument_pixels``): the previous frame's
        # tracks' k-1 pixels, (t_prev_ns, t_ns, ids, uv_left_prev, uv_right_prev), and the
        # mean camera motion of the last paper update, (t_prev_ns, t_ns, R_c, r_c).
        self._pixels_before: tuple[int, int, I64, F64, F64] | None = None
        self._k2: tuple[int, int, I64, F64, F64] | None = None
        self._motion_before: tuple[int, int, F64, F64] | None = None

    def _fresh(self, tr: StereoTracks | None) -> NDArray[np.bool_] | bool:
        """Features (M,) whose k-1 pixels no update has used (``single_use_pixels``, clones
        only): a pixel fused at k-1 has moved the clone, so triangulating it again at k would
        correlate the measurement noise with the state error."""
        last = self._fused
        if (tr is None or self.clones is None or self.shared
                or not self.options.single_use_pixels):
            return True
        if last is None or last[0] != tr.t_prev_ns:
            return True
        return ~_member(tr.track_id, last[1])

    def _near(self, tr: StereoTracks | None) -> NDArray[np.bool_] | bool:
        """Features (M,) whose disparity one frame earlier (k-2) is at least
        ``min_disparity_px``. Gating on the k-1 disparity itself would bias the triangulation
        that uses it (a far feature whose noise happened to enlarge its disparity passes, one
        whose noise shrank it does not); the k-2 pixels carry independent noise.

        A feature first seen at k-1 (or any feature when the k-2 frame is not the previous
        tracks' reference: the first frames, a gap) is gated on its k-1 disparity at
        ``NEW_FEATURE_DISPARITY_FACTOR`` times the threshold instead: so far from the noise
        the selection barely biases, and frames seconds apart, which share few tracks with
        the frame before, keep their features (issue 22: at 5 s spacing the k-2 gate alone
        left a median of 11 features per frame)."""
        d_min = self._min_disparity_px
        if tr is None or d_min <= 0.0:
            return True
        ids, disp = self._disparity_before
        disp_prev = tr.uv_left_prev[:, 0] - tr.uv_right_prev[:, 0]
        self._disparity_before = (tr.track_id, disp_prev)
        new = disp_prev >= NEW_FEATURE_DISPARITY_FACTOR * d_min
        if ids.size == 0 or self._disparity_t_ns != tr.t_prev_ns:
            self._disparity_t_ns = tr.t_ns
            return new
        self._disparity_t_ns = tr.t_ns
        found, j = find_ids(ids, tr.track_id)
        return np.where(found, disp[j] >= d_min, new)

    def _motion(
        self, ctx: FrameContext, tr: StereoTracks, dt_s: float, inc: ImuIncrement | None
    ) -> MotionFn | None:
        """Camera motion k-1 -> k of sigma points, ``X (S, nx) -> (R_c (S, 3, 3), r_c (S, 3))``:
        from the clone of the k-1 frame (``rotation="clone"``; None when there is none) or
        from the state at k (``vision_common.camera_motion``)."""
        rig, rot = self.rig, self.options.rotation
        if self.clones is not None:
            cols = self.clones.columns(ctx.ukf, tr.t_prev_ns)
            calib, td = self.clones.calib(ctx.ukf), self.clones.td(ctx.ukf, ctx.t_ns)
            return None if cols is None else (
                lambda X: clone_camera_motion(X, cols, rig, calib, td))
        return lambda X: camera_motion(X, dt_s, rig, rot, inc)

    def _model(self, uvl0: F64, uvr0: F64, motion: MotionFn, p_F: F64 | None = None) -> Any:
        """``h(X)`` from the k-1 pixels (M, 2): ``3d`` triangulates them (eq. 10; or takes
        ``p_F`` (M, 3)) and moves the points with each sigma point's camera motion, ``tc``
        transfers them (eq. 21)."""
        rig = self.rig
        if self.method == "3d":
            p = rig.triangulate(uvl0, uvr0) if p_F is None else p_F
            return lambda X: pixels_from_motion(*motion(X), p, rig)
        return lambda X: pixels_tc_from_motion(*motion(X), uvl0, uvr0, rig)

    def _pixels(self, R_c: F64, r_c: F64, uvl0: F64, uvr0: F64) -> tuple[F64, F64 | None]:
        """Predicted pixels (S, 4M) for the camera motions ``R_c`` (S, 3, 3), ``r_c`` (S, 3)
        from the k-1 pixels (M, 2), and (``3d``) the k-1 points (M, 3) they triangulate to."""
        if self.method == "3d":
            p_F = self.rig.triangulate(uvl0, uvr0)
            return pixels_from_motion(R_c, r_c, p_F, self.rig), p_F
        return pixels_tc_from_motion(R_c, r_c, uvl0, uvr0, self.rig), None

    def _bias(self, R_c: F64, r_c: F64, uvl0: F64, uvr0: F64) -> F64 | None:
        """Second-order bias (4M,) px of the predicted pixels from the k-1 pixel noise (the
        pixels' own std, not the scaled ``sigma_px``, which also covers model error), at the
        mean camera motion ``R_c`` (3, 3), ``r_c`` (3,); None when the noise is unknown or the
        bias is zero everywhere (nothing to correct)."""
        if not self._noise_known:
            return None
        rig, R1, r1 = self.rig, R_c[None], r_c[None]
        if self.method == "3d":
            def h_prev(ul: F64, ur: F64) -> F64:
                return pixels_from_motion(R1, r1, rig.triangulate(ul, ur), rig)[0]
        else:
            def h_prev(ul: F64, ur: F64) -> F64:
                return pixels_tc_from_motion(R1, r1, ul, ur, rig)[0]
        bias = previous_pixel_bias(h_prev, uvl0, uvr0, self._pixel_std_px)
        return bias if np.any(bias) else None

    def _instrument_pixels(self, tr: StereoTracks, idx: I64) -> tuple[F64, F64] | None:
        """The k-1 pixels (M, 2) left and right whose sigma-point predictions give the
        update's spread (``vision.instrument_points``): each feature's k-2 stereo point moved by
        the last update's mean camera motion k-2 -> k-1 and projected, its error independent
        of the k-1 and k pixels' noise; the k-1 pixels themselves where a feature has no k-2
        pixels. None where none has (no k-2 frame just before, no paper update there)."""
        k2, mo = self._k2, self._motion_before
        if (not self.options.instrument_points or k2 is None or mo is None
                or k2[1] != tr.t_prev_ns or mo[:2] != k2[:2]):  # fmt: skip
            return None
        found, j = find_ids(k2[2], tr.track_id[idx])
        j = j[found]
        p_Ckm1 = move_points(mo[2][None], mo[3][None],
                             self.rig.triangulate(k2[3][j], k2[4][j]))[0]
        ok = np.isfinite(p_Ckm1).all(axis=1) & (p_Ckm1[:, 2] > 0)
        if not ok.any():
            return None
        uv = project_stereo(p_Ckm1[ok], self.rig).reshape(-1, 4)
        uvl, uvr = tr.uv_left_prev[idx].copy(), tr.uv_right_prev[idx].copy()
        rows = np.flatnonzero(found)[ok]
        uvl[rows], uvr[rows] = uv[:, :2], uv[:, 2:]
        return uvl, uvr

    def _paper_features(
        self, ctx: FrameContext, X: F64, z: F64, uvl0: F64, uvr0: F64, motion: MotionFn,
        inc: ImuIncrement | None, dt_s: float, tr: StereoTracks, idx: I64,
    ) -> _Features:
        """The paper's ``tc``/``3d`` features ``idx`` of ``tr``: 4 pixels at k each, predicted
        from the k-1 pixels (second-order bias removed where the pixel noise is known), gated
        one by one.

        With instruments (``_instrument_pixels``) the prediction at the mean is the k-1
        pixels' and its spread over the sigma points the instruments': the spread is the
        update's regressor, and taken from the noisy k-1 pixels it shares their disparity
        noise with the residual, a regression on a noisy regressor (errors in variables): on
        the simulated village the translation tilted 0.24° toward the camera's +y, read as a
        constant pitch (probe 67; roll/pitch NEES 3.2 of 2)."""
        # One camera-motion evaluation for the sigma points and the mean (last row).
        R_all, r_all = motion(np.vstack([X, ctx.ukf.x[None, :]]))
        R_c, r_c = R_all[-1], r_all[-1]
        Y, p_F = self._pixels(R_all[:-1], r_all[:-1], uvl0, uvr0)
        uvl_h, uvr_h, p_h, offset = uvl0, uvr0, p_F, None
        instruments = self._instrument_pixels(tr, idx)
        if self.options.instrument_points:
            self._motion_before = (tr.t_prev_ns, tr.t_ns, R_c, r_c)
        if instruments is not None:
            uvl_h, uvr_h = instruments
            Y_h, p_h = self._pixels(R_all, r_all, uvl_h, uvr_h)
            offset = self._pixels(R_all[-1:], r_all[-1:], uvl0, uvr0)[0][0] - Y_h[-1]
            Y = Y_h[:-1] + offset
        bias = self._bias(R_c, r_c, uvl0, uvr0)
        if bias is not None:
            Y = Y - bias
        # Per-feature 4x4 noise: pixel noise at k plus the k-1 pixel noise carried through
        # triangulation/transfer (dominant for far points), and in "imu" mode the IMU
        # increment's noise as a feature-correlated factor G (4M, 6). Closed form at the mean
        # state (``analytic_noise``; tests check it against finite differences of the model).
        R_blocks, G = analytic_noise(
            R_c, r_c, uvl0, uvr0, self.rig, self.sigma_px, inc, dt_s, self._imu_noise, p_F
        )
        pts = ctx.ukf.points
        keep, finite, nis = feature_gate(
            Y, pts.Wm, pts.Wc, z, R_blocks, self.options.feature_gate_probability, G
        )
        # Near-zero disparity makes the prediction hypersensitive to the k-1 pixels (|J| > 100):
        # such features carry no information and would make R_blocks numerically singular.
        sane = np.abs(R_blocks.reshape(-1, 16)).max(axis=1) < (100.0 * self.sigma_px) ** 2

        def model(kept: I64) -> Callable[[F64], F64]:
            h = self._model(uvl_h[kept], uvr_h[kept], motion, None if p_h is None else p_h[kept])
            if offset is not None:
                h = _debiased(h, -offset.reshape(-1, 4)[kept].reshape(-1))
            return h if bias is None else _debiased(h, bias.reshape(-1, 4)[kept].reshape(-1))

        return _Features(Y, z, R_blocks, G, keep & sane, finite & sane, nis, model)

    def _two_view_features(
        self, ctx: FrameContext, tr: StereoTracks, X: F64, z: F64, uvl0: F64, uvr0: F64,
        motion: MotionFn,
    ) -> _Features:
        """Each feature's point marginalised over its 8 pixels at k-1 and k
        (``navigation.vision_two_view``): 5 numbers each, gated one by one, linearised at the
        frame's egomotion (from all of ``tr``) when the prior's mean fits the pixels poorly.
        Clones only, so no IMU-increment term."""
        R_all, r_all = motion(np.vstack([X, ctx.ukf.x[None, :]]))
        z8 = np.concatenate([uvl0, uvr0, z.reshape(-1, 4)], axis=1)

        def egomotion() -> tuple[F64, F64] | None:
            # The motion only: its covariance (half the estimate's cost) is made when a
            # fallback to fusing the egomotion asks for it (``_egomotion_of``).
            ego = self._egomotion_of(tr, covariance=False)
            if ego is None:
                return None
            self.counters.frames_linearised_at_egomotion += 1
            # p_Ck = R p_Ckm1 + p  is  d_k = R_c d - r_c
            return np.asarray(ego.R_Ck_Ckm1, float), -np.asarray(ego.p_Ck_Ckm1, float)

        tv = TwoViewFeatures.build(R_all, r_all, z8, self.rig.triangulate(uvl0, uvr0), self.rig,
                                   self._two_view_sigma_px,
                                   egomotion if self._noise_known else None)  # fmt: skip
        keep, finite, nis = tv.gate(ctx.ukf.points, self.options.feature_gate_probability)
        return _Features(tv.Y, tv.z, tv.R_blocks, None, keep, finite, nis,
                         lambda kept: tv.model(kept, motion), tv.N)  # fmt: skip

    def update(self, ctx: FrameContext) -> UpdateStats | None:
        """Fuse the frame at ``ctx.t_ns`` (see the module docstring)."""
        self.counters.frames += 1
        tr, inc = tracks_with_prior(self.source, self._prior, ctx)
        self.last_tracks = tr
        if self.checks is not None:
            self.checks.observe_frame(tr, ctx)
        return self._fuse(ctx, tr, inc)

    def last_egomotion(self) -> Egomotion | None:
        """The egomotion of the last frame's tracks (computed once; None without one)."""
        return None if self.last_tracks is None else self._egomotion_of(self.last_tracks)

    def _fuse(
        self, ctx: FrameContext, tr: StereoTracks | None, inc: ImuIncrement | None,
        keyframe: bool = False,
    ) -> UpdateStats | None:
        """Fuse the tracks ``tr`` ending at ``ctx.t_ns`` (``keyframe``: from a stored keyframe
        put in the state, ``_relocalise``: two-view, never relocalised again)."""
        c = self.counters
        # The last fused frame's pixel correlation serves this frame's pixel update only.
        corr = vision_correlated.take(ctx.ukf, self._correlation)
        self._correlation = None
        usable = (
            np.zeros(0, bool) if tr is None
            else tr.inlier & np.isfinite(tr.p_Ckm1_F).all(axis=1) & (tr.p_Ckm1_F[:, 2] > 0)
        )
        # A short frame with correlated pixels is fused like a shared one: two-view, every
        # feature, no disparity gate (``features_for_gap``); a longer one as by default, with
        # every feature too where it takes the two-view model (the correlation, which needs
        # the two-view null spaces, replaces single use).
        short = self.correlated and tr is not None and self.options.is_short(
            (tr.t_ns - tr.t_prev_ns) * 1e-9)
        two_view = short or self.two_view or (
            (ctx.two_view or keyframe) and self._two_view_in_gaps)
        # the k-2 pixels of the instruments (a stored keyframe's tracks are no frame before)
        if self.options.instrument_points and not keyframe:
            self._k2 = self._pixels_before
            self._pixels_before = None if tr is None else (
                tr.t_prev_ns, tr.t_ns, tr.track_id, tr.uv_left_prev, tr.uv_right_prev)
        near = True if short else self._near(tr)
        if short:
            self._near(tr)  # it keeps the disparities of the frame before
        if not (self.correlated and two_view):
            usable &= self._fresh(tr)
        # The two-view model estimates each point in inverse depth from all 8 pixels, so a
        # far feature neither biases it nor leaves the linear range (the reasons for the gate):
        # features below the disparity gate fill the frame up to ``max_features`` when too few
        # pass it (``two_view_fill_far``).
        far = (usable & np.logical_not(near) if two_view and self.options.two_view_fill_far
               else np.zeros_like(usable))
        usable &= near
        if tr is None or tr.t_ns <= tr.t_prev_ns:
            c.frames_without_tracks += 1
            return None
        if usable.sum() + far.sum() < self.options.min_features:
            # Too few features for the pixel model (the k-1 pixels of the others were fused at
            # the last update, or their disparity is too small to triangulate), yet a frame
            # with enough tracked features may still link to k-1 through its egomotion, which
            # uses every one of them.
            ego = None
            if int(tr.inlier.sum()) >= self.options.min_features:
                ego = self._egomotion_update(ctx, tr)
            if ego is not None and ego.accepted:
                return ego
            if not keyframe and self.relocaliser is not None and (stats := self.relocaliser.attempt(
                    ctx, lambda kf_tr: self._fuse(ctx, kf_tr, None, keyframe=True))) is not None:
                return stats
            c.frames_without_tracks += 1
            return ego
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        # More features in a short frame with shared pixels (``VisionOptions.features_for_gap``).
        n_max = (self.options.features_for_gap(dt_s) if self.shared or short
                 else self.options.max_features)
        idx = _subsample(np.flatnonzero(usable), n_max)
        if far.any() and (n_max is None or idx.size < n_max):
            room = None if n_max is None else n_max - idx.size
            idx = np.sort(np.concatenate([idx, _subsample(np.flatnonzero(far), room)]))
        z = stack_pixels(tr.uv_left[idx], tr.uv_right[idx])
        uvl0, uvr0 = tr.uv_left_prev[idx], tr.uv_right_prev[idx]
        if self._imu is None or self.options.rotation != "imu":
            inc = None
        elif inc is None:  # no prior, or it spanned another interval
            inc = self._imu.between(ctx, tr.t_prev_ns, tr.t_ns)
        motion = self._motion(ctx, tr, dt_s, inc)
        if motion is None:  # no clone of the k-1 frame (e.g. the first frame)
            c.frames_without_tracks += 1
            return None
        X, _ = ctx.ukf.sigma_points()  # reused by the update below (same state)
        if two_view:
            f = self._two_view_features(ctx, tr, X, z, uvl0, uvr0, motion)
        else:
            f = self._paper_features(ctx, X, z, uvl0, uvr0, motion, inc, dt_s, tr, idx)
        c.features_invalid += int((~f.finite).sum())
        c.features_gated += int((f.finite & ~f.keep).sum())
        n_valid, n_kept = int(f.finite.sum()), int(f.keep.sum())
        wide = n_valid < max(self.options.min_features, 0.5 * idx.size)
        refused = n_kept < max(self.options.min_features,
                               self.options.frame_min_inlier_fraction * n_valid)  # fmt: skip
        ego = None
        if wide or refused:
            # The prior cannot be linearised over (most features invalid) or disagrees with
            # the frame: its egomotion instead (``vision_egomotion``), gated like any sensor.
            ego = self._egomotion_update(ctx, tr)
            if ego is not None and ego.accepted:
                return ego
        if n_valid < self.options.min_features:
            c.frames_without_tracks += 1
            return ego
        if refused:
            # A rejection (the consistency monitor counts it, and a run of them inflates the
            # covariance).
            c.frames_rejected += 1
            c.frames_gated += 1
            return self._refused(f, n_valid) if ego is None else ego
        kept = np.flatnonzero(f.keep)
        block = _whitened_block(f"vision_{self.method}", kept, X, f.Y, f.z, f.R_blocks, f.G,
                                f.model(kept))  # fmt: skip
        ids_kept = tr.track_id[idx[kept]]
        white = None
        if self.correlated and f.N is not None:
            block, n_corr, white = vision_correlated.with_correlation(
                block, ctx.ukf, corr, tr.t_prev_ns, ids_kept, f.N[kept], self._two_view_sigma_px)
            c.features_correlated += max(n_corr, 0)
            c.frames_correlation_dropped += int(n_corr < 0)
        stats = apply_blocks(ctx, [block, *ctx.extra])
        if stats.accepted:
            c.frames_fused += 1
            c.features_fused += kept.size
            self._fused = (tr.t_ns, np.sort(ids_kept))
            if self.correlated and f.N is not None:
                self._correlation = vision_correlated.after_update(
                    ctx.ukf, block, white, ids_kept, f.N[kept], self._two_view_sigma_px, tr.t_ns)
            return stats
        if not ctx.extra and not wide:  # a wide prior's fallback was tried above, same state
            ego = self._egomotion_update(ctx, tr)
            if ego is not None and ego.accepted:
                return ego
        c.frames_rejected += 1
        return stats

    def _egomotion_update(self, ctx: FrameContext, tr: StereoTracks) -> UpdateStats | None:
        """Fuse the frame's egomotion against the clone of the k-1 frame, counted as a fused
        frame when accepted (None: no clone, no egomotion or an unusable covariance)."""
        if self.clones is None or not self.options.egomotion_fallback:
            return None
        cols = self.clones.columns(ctx.ukf, tr.t_prev_ns)
        if cols is None:
            return None
        ego = self._egomotion_of(tr)
        if ego is None:
            return None
        calib, rig = self.clones.calib(ctx.ukf), self.rig
        td = self.clones.td(ctx.ukf, ctx.t_ns)
        block = egomotion_block(
            "vision_egomotion", ego, self.options,
            lambda X: predict_egomotion_clone(X, cols, rig, calib, td))
        if block is None:
            return None
        stats = apply_blocks(ctx, [block])
        if not stats.accepted:
            stats = fuse_inflated(ctx, block, stats, self.options.lc_inflate_max)
            self.counters.frames_inflated += int(stats.accepted)
        if stats.accepted:
            self.counters.frames_fused += 1
            self.counters.frames_egomotion += 1
        return stats

    def _egomotion_of(self, tr: StereoTracks, covariance: bool = True) -> Egomotion | None:
        """``tracks_egomotion`` of ``tr``, computed once: a two-view frame linearised at its
        egomotion may fall back to fusing it. ``covariance`` False: the motion is all the
        caller reads (its ``cov`` may be NaN); asked for later, the covariance is made by
        estimating again (the same seed gives the same motion)."""
        memo = self._egomotion_memo
        if memo is None or memo[0] is not tr or (covariance and not memo[2]):
            ego = tracks_egomotion(tr, self.rig, seed=self.counters.frames,
                                   bundle=self.options.bundle_for(self.method),
                                   covariance=covariance)  # fmt: skip
            memo = self._egomotion_memo = (tr, ego, covariance or ego is None)
        return memo[1]

    def _refused(self, f: _Features, n_valid: int) -> UpdateStats:
        """The stats of a frame refused by the frame test: the NIS of its valid features
        against the chi-square quantile of ``feature_gate_probability`` for their dof."""
        nb = f.R_blocks.shape[1]
        dof = nb * n_valid
        p = self.options.feature_gate_probability
        gate = chi2_gate(p, dof) if p is not None else np.inf
        return UpdateStats(f"vision_{self.method}", False, float(np.sum(f.nis[f.finite])), dof,
                           float(gate))  # fmt: skip

    def after_frame(self, ctx: FrameContext) -> None:
        """Once per frame, after ``update``: keep the clone the next frame needs, and the
        frame as a keyframe when it was fused."""
        if self.clones is not None:
            self.clones.after_frame(ctx.ukf, ctx.t_ns, next_reference_ns(self.source, ctx.t_ns))
        if self.relocaliser is not None:
            self.relocaliser.remember(ctx, self.counters.frames_fused > self._fused_before)
        self._fused_before = self.counters.frames_fused

    def summary(self) -> dict[str, Any]:
        """Counters and settings for ``report.json``."""
        out: dict[str, Any] = self.counters.as_dict()
        out.update(source=self.source.kind, sigma_px=self.sigma_px, shared_pixels=self.shared,
                   correlated_pixels=self.correlated, rotation=self.options.rotation,
                   frontend_status=dict(getattr(self.source, "status_counts", {})),
                   **stereo_check_summary(self.source))
        if self.checks is not None:
            out.update(self.checks.summary())
        if self.clones is not None:
            out.update(self.clones.summary())
        if self.relocaliser is not None:
            out.update(self.relocaliser.summary())
        return out


def _whitened_block(
    name: str, kept: I64, X: F64, Y: F64, z: F64, R_blocks: F64, G: F64 | None, h_kept: Any
) -> MeasurementBlock:
    """The kept features (K,) as one block with unit diagonal noise: each feature's d numbers
    (``R_blocks`` (M, d, d): 4 pixels, or 5 for the two-view model) whitened (rows times
    ``L_m^-1``, ``R_m = L_m L_m^T``) so the filter takes its fast Woodbury path instead of a
    dense nz x nz Cholesky. The IMU term ``G`` (dM, 6), common to all features, is whitened too:
    ``(I + Gw Gw^T)^-1/2`` is identity minus a rank-6 correction. ``h`` reuses the predictions
    ``Y`` (S, dM) made for the sigma points ``X`` (and calls ``h_kept`` for any other points)."""
    nb = R_blocks.shape[1]
    rows = (nb * kept[:, None] + np.arange(nb)).reshape(-1)
    L = np.linalg.cholesky(R_blocks[kept])  # (K, d, d)
    white = Whitening.of(L, None if G is None else whiten_chol(G[rows].T, L).T)
    # The sigma points' predictions and z whitened in one pass.
    YZ = white(np.vstack([Y[:, rows], z[rows][None, :]]))
    h = CachedModel(lambda X_: white(h_kept(X_)), X, YZ[:-1])
    return MeasurementBlock(name=name, h=h, z=YZ[-1], R=np.ones(rows.size))


def imu_and_prior(
    history: ImuHistory | None, rig: Rig, options: VisionOptions,
    source: FeatureFrames | ImageFrames,
) -> tuple[ImuIncrements | None, MotionPrior | None]:
    """IMU samples when the ``imu`` rotation or the motion prior needs them; a prior only for the
    image front end (recorded tracks need none) with an IMU."""
    wanted = options.motion_prior or options.motion_prior_after_s is not None
    use_prior = wanted and isinstance(source, ImageFrames) and history is not None
    if (options.rotation != "imu" and not use_prior) or history is None:
        return None, None
    imu = ImuIncrements(history, np.asarray(rig.gravity_W, float), rig.imu, options.imu_noise)
    if not use_prior:
        return imu, None
    after_s = None if options.motion_prior else options.motion_prior_after_s
    prior_opts = MotionPriorOptions(options.motion_prior_inflation, options.motion_prior_min_std,
                                    after_s=after_s)  # fmt: skip
    return imu, MotionPrior(imu, source.rig, prior_opts)


def tracks_with_prior(
    source: FeatureFrames | ImageFrames, prior: MotionPrior | None, ctx: FrameContext
) -> tuple[StereoTracks | None, ImuIncrement | None]:
    """Tracks at ``ctx.t_ns`` (the image front end gets the motion prior when there is one) and
    the prior's IMU increment when the tracks span the same interval (reusable)."""
    if prior is None or not isinstance(source, ImageFrames):
        return source.tracks_at(ctx.t_ns), None
    t_ref = source.reference_time_ns()
    if not prior.wanted(ctx.t_ns, t_ref):
        return source.tracks_at(ctx.t_ns), None
    ego, inc = prior.for_frame(ctx, t_ref)
    tr = source.tracks_at(ctx.t_ns, ego)
    if tr is None or inc is None or tr.t_prev_ns != t_ref:
        return tr, None
    return tr, inc


def apply_blocks(ctx: FrameContext, blocks: list[MeasurementBlock]) -> UpdateStats:
    """One stacked update through the runner (``ctx.apply``) or the filter directly."""
    if ctx.apply is not None:
        return ctx.apply(blocks)
    if len(blocks) != 1:
        raise ConfigError("stacked updates need the runner's ctx.apply")
    b = blocks[0]
    return ctx.ukf.update(b.h, b.z, b.R, ctx.gate_probability, b.residual, b.name)


# ``fuse_inflated``: scalings tried before an egomotion is refused after all.
_INFLATE_TRIES = 3


def fuse_inflated(
    ctx: FrameContext, block: MeasurementBlock, refused: UpdateStats, limit: float | None
) -> UpdateStats:
    """An egomotion ``block`` refused by its gate (``refused``) whose NIS is at most ``limit``
    times the gate, fused with the state's motion covariance
    (``fault_handling.scale_motion_covariance``: pose, velocity, biases, clones) and its own
    scaled by s = NIS / gate: the gain is the ungated update's, the NIS lands on the gate, and
    the posterior covariance is s times wider, owning the disagreement. Else ``refused`` (the
    state untouched; ``limit`` None: always).

    Each egomotion links a frame to the one before: refusing one leaves the IMU's motion over
    that interval in the state for good. Simulated 2 Hz flights, seed 2 at 30.5 s: a correct
    egomotion (bundle covariance, 0.01° in rotation) against an IMU interval in its noise's
    tail, NIS 22-27 at a gate of 22.5 (6 dof); refused, the attitude kept a 1.3° error and
    ``lc``'s ATE tripled. Scaling the egomotion's covariance alone does not move such an NIS
    (the prediction's spread dominates it). A wrong egomotion (a failed RANSAC, a moving
    object) lands far above the gate and is still refused."""
    if limit is None or not np.isfinite(refused.nis) or refused.nis > limit * refused.gate:
        return refused
    ukf = ctx.ukf
    P0, scale, stats = ukf.P, 1.0, refused
    for _ in range(_INFLATE_TRIES):
        # An iterated update's NIS (long frames) moves with the scale but not as 1 / s; the
        # margin keeps round-off from leaving the NIS a hair above the gate.
        scale *= stats.nis / stats.gate * (1.0 + 1e-6)
        ukf.P = P0
        scale_motion_covariance(ukf, scale)
        stats = apply_blocks(ctx, [replace(block, R=scale * block.R), *ctx.extra])
        if stats.accepted:
            log.debug("egomotion at t=%d ns fused at %.2fx the covariance (NIS %.1f, gate %.1f)",
                      ctx.t_ns, scale, refused.nis, refused.gate)  # fmt: skip
            return stats
    ukf.P = P0
    return refused
