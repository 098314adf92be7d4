"""The vision updates' options (``RunConfig.vision``; ``navigation.vision``)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from svains.errors import ConfigError
from svains.models.vision_common import ROTATION_MODELS
from svains.navigation.option_types import check_types

SourceName = Literal["auto", "features", "images"]
MotionModel = Literal["clone", "linear", "exp", "imu"]  # ``MOTION_MODELS``


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
# The same factor for an egomotion from the two-frame bundle adjustment
# (``frontend.egomotion_bundle``: the points fitted with the motion to all four pixels, features
# gated on their joint residual). Its covariance is honest and its per-frame bias gone, so its
# errors no longer drift together (features0, NEES of 10 summed frames 2.8-5.7 against 18.2
# for RANSAC's on the village, see ``BundleOptions``). Factor 2, not 1: consecutive egomotions
# share the pixels of the frame between them (as ``vision_pixels.SHARED_PIXEL_VARIANCE``); the
# village's 10 seeds at 5 Hz give NEES 14.1 with 1 (above the 95 % band, 6.57-11.81), 11.0
# with 2, ATE 0.072 / 0.070 m (2026-12-05).
LC_COV_SCALE_BUNDLE = 2.0

# Vision motion models: the state-at-k ones of ``models.vision_common`` and ``clone`` (the pose
# at k-1 cloned into the state, ``navigation.vision_clones``; exact relative motion).
MOTION_MODELS = (*ROTATION_MODELS, "clone")


@dataclass(frozen=True)
class VisionOptions:
    """Vision-update settings (``RunConfig.vision``).

    ``source``: where tracks come from in a replay (``features``: a recorded ``features0``
    stream, ``images``: the stereo front end, ``auto``: features when the data set has them).
    ``pixel_noise_std`` px (None: the features0 value, 1 px for images; a replay resolves it)
    times ``pixel_noise_scale`` (None: ``noise_scale()``, 1 with clones, 2 for the approximate
    motion models); ``feature_gate_probability`` per-feature chi-square(4) gate (None: off);
    ``max_features`` per frame fused by the pixel models of ``tc``/``3d`` (evenly subsampled;
    None: all; ``lc`` and ``vo`` fuse the egomotion of every tracked feature, whatever it says),
    ``max_features_short`` in a frame at most ``short_gap_s`` (s; None: none is short) after the
    one before, with shared pixels (``features_for_gap``); ``rotation`` is the motion model
    between frames: "clone" (default: the pose at k-1 cloned into the state, exact relative
    motion, ``navigation.vision_clones``), "linear" (paper eq. 18), "exp" or "imu" (relative
    motion from the IMU samples between the frames: ``models.vision_imu``); ``shared_pixels``
    (clones, ``tc``/``3d``; opt-in, see the comment at the field): every frame takes the
    two-view model (``two_view``, each feature's point marginalised over its 8 pixels at k-1
    and k) and each feature's pixels enter both
    frame pairs they belong to (k-1 -> k and k -> k+1), each time at twice their variance: a
    pixel's information is split between its two updates, so none is counted twice and none is
    left out (``vision_pixels.SHARED_PIXEL_VARIANCE``). ``correlated_pixels`` (opt-in; clones,
    ``tc``/``3d``, recorded features or a given ``pixel_noise_std``: the correlation is in the
    pixels' noise units) fuses every feature in both its frame pairs at its full variance and
    takes out of the second pair what the first left correlated with the state
    (``navigation.vision_correlated``, ``filter.noise_correlation``: exact for linear models);
    frames at most ``short_gap_s`` apart are fused like shared ones (two-view, no disparity
    gate, ``features_for_gap``), longer ones as by default but with every feature. Measured
    2026-12-06 (``docs/results/low-rate.md``), default -> correlated: simulated village 5 Hz,
    10 seeds GPS-denied, ``3d`` ATE 0.094 -> 0.054 m, NEES 11.58 -> 9.10 (band 6.57-11.81);
    EuRoC V1_01 every frame 0.037 -> 0.018 m, every 10th / 25th 0.070 / 0.514 -> 0.070 /
    0.509 m; simulated 2 Hz flights 0.0371 -> 0.0279 m (0.0331 -> 0.0230 at ``vo``'s stamps);
    costs: EuRoC irregular frames 0.286 -> 0.310 m (max 0.660 -> 0.786), 1.4-1.7x the wall time
    of a 5 Hz run (2026-12-07), and the smoother, which takes measurement noise as white, does
    not know the correlation; starts and checks tuned with single-use pixels are not ready for
    it (``docs/results/low-rate.md``, "Correlated pixels as the default?"). Off:
    ``single_use_pixels`` (clones) lets each feature pixel enter one update only (a feature
    fused at k-1 is not triangulated again at k, every other frame of a long track is lost);
    ``min_disparity_px`` (None:
    ``min_disparity()``) drops features whose disparity one frame earlier is smaller;
    ``frame_stride`` uses every n-th stereo frame; ``egomotion_bundle`` refines the egomotion of
    pre-tracked features by a two-frame bundle adjustment (None: ``vo`` only, see
    ``bundle_for``); ``lc_bundle_short`` (opt-in) refines ``lc``'s too when its recorded frames
    are at most ``short_gap_s`` apart (``bundle_max_gap_for``); ``lc_cov_scale`` multiplies the
    egomotion covariance (None: ``lc_scale()``: 30 for RANSAC's estimate, 2 for the bundle's);
    ``lc_min_std`` (rad, m) floors its standard deviations; ``lc_inflate_max``: an egomotion
    refused by the gate with an NIS at most this many times the gate is fused after all, the
    state's motion covariance and its own scaled by NIS / gate (``vision_pixels.fuse_inflated``;
    None: refused as before), by ``lc`` and, since 2026-12-05, by the ``tc``/``3d`` egomotion
    fallback. Each egomotion links a frame to the one before, so a refused one keeps the IMU's
    error over its interval for good: simulated 2 Hz flights (seed 2, a tail-end IMU interval
    at 30.5 s) ``lc`` with ``lc_bundle_short`` 0.042 -> 0.021 m (V2_02), 0.062 -> 0.021 m
    (MH_03); the fault bench's gyro bias step, seed 4, ``3d`` 2.97x -> 1.3x its clean error
    (the bias alarm 5.5 s sooner); EuRoC every 10th frame ``3d`` 0.099 -> 0.070 m, irregular
    frames 0.291 -> 0.286 m; ``imu_noise`` adds the IMU
    increment's noise (``rotation="imu"``) to the pixel covariance as a feature-correlated
    term; ``frame_gyro_walk`` (``imu`` only, applied by ``tune_for_frames``) instead lets the
    gyro-bias state absorb it, see there; ``motion_prior`` hands the image front end the
    camera motion the filter predicts between its frames (``vision_motion.MotionPrior``), with
    ``motion_prior_inflation`` (variance factor) and ``motion_prior_min_std`` (rad, m) floors
    (off by default: on the simulated village sets, whose gyro is noisy, ``3d`` with the prior
    was better on the 20 Hz bench set, 0.041 m against 0.045 m RMSE, see
    ``bench/bench_methods.py``, and worse on the 2 Hz demo flight, 0.358 m against 0.259 m);
    ``motion_prior_after_s`` (s; None: never) hands it over, with ``motion_prior`` off, only
    for frames at least that long after the front end's reference frame, where KLT cannot
    bridge the motion unaided and a few tracks gone wrong can agree on a wrong motion: on
    rendered keyframes 0.05-7 s apart (``bench/rendered_keyframes.py``, 6 runs) ``3d`` 0.795
    -> 0.237 m mean ATE (no run above 1 m instead of one at 3.2 m, NEES 82.9 -> 3.5) with an
    IMU as quiet as its data sheet, 0.529 -> 0.508 m with one 5.5x / 7.9x noisier (and 0.214 /
    0.432 m with the re-acquisition's own inlier floor inside the prior's windows,
    ``ReacquireOptions.min_inlier_fraction_with_prior``); frames closer together (the 2 Hz
    demo, KITTI raw at 5 Hz) are unchanged; KITTI raw thinned to 0.5 Hz 2.45 -> 2.83 m;
    ``estimate_extrinsics`` (clones only) adds the camera-IMU rotation correction to the state
    with prior standard deviation ``extrinsics_std_deg`` per axis
    (``navigation.vision_clones``; the run writes ``camchain_estimated.yaml``). Off by default:
    GPS-denied, the rotation about the axes near the direction of travel and the vertical is
    barely observable and the estimate drifts, costing accuracy (KITTI raw, 3d from the
    reference start: final error 1.41 % -> 1.73 %, NEES 67 -> 34; simulated village 60 s,
    seeds 0-1, exact calibration: RMSE 0.239/0.277 m -> 0.407/0.289 m). With GPS it finds
    KITTI's rotation error (0.36 +- 0.13 deg about the camera x axis, as the tilt against the
    reference shows): see ``bench/kitti_extrinsic_check.py --from-gps``.
    ``consider_extrinsics_std_deg`` (clones only; None: off): the camera rotation's error is
    not estimated but *considered*: ``δφ_C`` joins the state with this standard deviation per
    axis (the calibration's accuracy, as its user knows it) as a Schmidt consider parameter the
    filter never updates, so the covariance carries what a rotation error that size does
    (``CloneWindow``, ``Manifold.consider``). Opt-in: on KITTI raw (0.5°) the covariance gets
    honest (``3d`` GPS-denied NEES 79 -> 38, the outage run's 11.3 -> 8.3) while a right
    calibration loses 13-35 % of its accuracy (``docs/results/kitti.md``). Not with the
    smoother (``RunConfig`` refuses the two): its RTS pass is no smoother for a Schmidt run.
    ``estimate_time_offset``
    (clones only) adds the camera-IMU time offset's residual (s, Kalibr's ``t_imu = t_cam +
    timeshift_cam_imu``, on top of the calibration's own offset, which stays applied to the
    image stamps) to the state with prior standard deviation ``time_offset_std_ms``
    (``navigation.vision_clones``; reported as ``vision.time_offset_ms`` and written to
    ``camchain_estimated.yaml``). Off by default: where the stamps are already right it gains
    nothing measurable and costs on KITTI raw (``3d`` GPS-denied final error 1.353 -> 1.500 %,
    ATE 0.810 -> 0.811 m, estimate -4.8 +- 2.6 ms), and with a gyro as noisy as the paper's
    (7 deg/s per sample) it is biased (the demo flight at 2 Hz, features: +15.0 +- 1.8 ms for a
    true 0). Turn it on for unsynchronised rigs: a 50 ms offset costs 15x the ATE at 20 Hz
    and diverges at 5 Hz on the simulator, and the estimate recovers it within 0.6 ms
    (``docs/results/time-offset.md``). ``update_iterations``
    linearises every vision update that many times over its posterior (``filter.iterated``; 1:
    the plain sigma-point update). Off by default: on KITTI raw ``3d`` GPS-denied 3 gave 1.354
    -> 1.350 % and NEES 73.7 -> 73.4 for 13 % more wall time; across IMU gaps the Navigator
    iterates anyway (``FaultOptions.gap_vision_iterations``). ``two_view`` (``tc``/``3d`` with
    ``rotation="clone"`` and ``single_use_pixels`` only, which keep the k-1 pixels unfused):
    estimate each feature's point from both frames' 8 pixels and fuse the 5 numbers free of it
    (``navigation.vision_two_view``) instead of taking the k-1 stereo point as exact (``3d``) or
    transferring the k-1 pixels (``tc``, the same prediction in a rectified pair). Off by
    default, i.e. the paper's models; across IMU gaps the Navigator uses it anyway
    (``FaultOptions.gap_vision_two_view``). On KITTI raw ``3d`` GPS-denied it gave 1.354 ->
    1.093 % final error but NEES 73.7 -> 92.1 and 60 % more wall time; re-measured 2026-12-04:
    1.353 -> 1.093 %, NEES 73.7 -> 92.0, wall time within 3 % (3 runs each: 3.79-3.97 s
    against 3.91-3.96 s). ``instrument_points`` (the paper's models, frames in a row): the
    sigma points' spread of the prediction, the update's regressor, from each feature's k-2
    stereo point moved by the last update's mean motion rather than from the noisy k-1 pixels
    the residual also holds (an errors-in-variables bias: a constant 0.25° pitch on the
    simulated village, probe 67); the prediction at the mean stays the k-1 pixels'. Off by
    default: it takes the village's NEES from 11.58 to 8.52 and EuRoC's every frame from 0.037
    to 0.029 m, but on GPS-aided 5 Hz test flights it loses accuracy (a smoothed outage 0.037
    -> 0.100 m; ``docs/results/simulator.md``).

    The frame test (``tc``/``3d``): each feature is gated on its own
    (``feature_gate_probability``) and a frame is refused, and counted as a rejection, when
    fewer than ``frame_min_inlier_fraction`` of its valid features pass (the prediction and the
    frame disagree); otherwise the passing features are fused with no chi-square test of the
    stacked frame unless ``frame_gate_probability`` is set; a frame whose stacked NIS per
    degree of freedom exceeds ``frame_max_nis_per_dof`` (3; consistent frames 2 s apart on the
    real EuRoC IMU reach 1.8 at the 90th percentile) is not fused: its pixels could not be
    linearised over the prior (after a long interval its sigma points span metres). A
    whole-frame test over ~480 pixel residuals at 0.999 refused a frame once its NIS per dof
    exceeded 1.21: after a 2 s gap on a real MAV IMU the first refusals added IMU-only drift
    and every later frame was refused
    (issue 22; OpenVINS and S-MSCKF gate features only, too). ``egomotion_fallback`` (clones
    only): a frame refused so, or whose features are mostly invalid over a prior too wide for
    the pixel model, fuses the frame's egomotion instead, as ``lc`` does
    (``navigation.vision_egomotion``). A frame more than ``iterate_after_s`` after the previous
    one is linearised ``long_iterations`` times (``filter.iterated``): its prior is
    wide against the pixels (EuRoC, every 25th frame at 5 Hz: ATE 27 m with one linearisation,
    2.7 m with three; every 10th: 0.115 -> 0.101 m). Such a frame also takes the two-view
    model (``two_view_after_long``, clones and single-use pixels only): its k-1 stereo points
    seen from metres away are no longer exact enough to be taken as known; where the prior's
    mean motion fits the pixels poorly and their noise is known (recorded features, or
    ``pixel_noise_std``), the points are refined at the frame's own egomotion
    (``navigation.vision_two_view``; EuRoC irregular frames 0.316 -> 0.312 m, simulated 0.5 Hz
    flights 0.425 -> 0.371 m). ``two_view_fill_far`` (on by default since 2026-12-05): a
    two-view frame fills up to ``max_features`` with the features below the disparity gate.
    The gate guards the paper's model, which takes the k-1 stereo point as exact; the two-view
    model estimates each point in inverse depth from its 8 pixels, and far
    features carry the rotation. Features that pass the gate still come first, so a near scene
    fuses what it fused before. Measured (``docs/results/low-rate.md``): simulated flights along
    the EuRoC trajectories (median disparity 3.7 px, 78 % of the features below the 6 px gate),
    ``3d`` mean ATE 0.056 -> 0.037 m at 2 Hz and 0.885 -> 0.673 m at 0.5 Hz; EuRoC V1_01 every
    10th / 25th frame 0.098 -> 0.072 m / 0.860 -> 0.807 m; irregular EuRoC frames over seeds
    0-29 0.329 m either way. It was not the default while two-view points were refined at the
    prior's mean only: the fault bench's gyro bias step cost ``3d`` 1.72x its clean error. With
    them refined at the egomotion where the mean fits poorly, on against off (2026-12-05):
    irregular EuRoC 0.312 -> 0.291 m (seeds 10-29 0.265 -> 0.264), simulated flights 2 Hz
    0.056 -> 0.037 m and 0.5 Hz 0.371 -> 0.218 m, fault bench ``3d`` all at once 1.69x ->
    1.40x, GPS ramp 1.63x -> 1.48x; costs: the gyro bias step 0.95x -> 1.33x (one seed 2.97x,
    NEES 24.6; 1.12x since the egomotion fallback is fused inflated, ``lc_inflate_max``),
    clean 0.0811 -> 0.0826 m, EuRoC every 10th / 25th frame 0.096 -> 0.099 m / 0.507 ->
    0.514 m (docs/results/low-rate.md).

    ``relocalise`` (``tc``/``3d``/``lc`` with clones): a frame that lost its link to the frame
    before is fused against a stored keyframe (one at most every ``keyframe_spacing_s``, at
    most ``max_keyframes``) the source matches it with by at least
    ``relocalise_min_features`` features (recorded features: by their ids; images: by ORB
    descriptors, among the keyframes that looked the same way from nearby), its pose taken into
    the state for that update as independent of it, each block's covariance inflated so that
    the update stays consistent (at least ``relocalise_inflation`` times), and only while the
    state's position variance is ``relocalise_min_drift`` (> 2) times the keyframe's
    (``navigation.relocalise``). EuRoC irregular frames ``3d`` 0.402 -> 0.316 m, ``lc`` 0.361
    -> 0.329 m; rendered keyframes from images ``3d`` 0.428 -> 0.275 m.
    """

    source: SourceName = "auto"
    pixel_noise_std: float | None = None
    pixel_noise_scale: float | None = None
    feature_gate_probability: float | None = 0.999
    max_features: int | None = 120
    max_features_short: int | None = 300
    short_gap_s: float | None = 1.0
    min_features: int = 3
    rotation: MotionModel = "clone"
    frame_stride: int = 1
    max_row_diff_px: float | None = 2.0
    lc_cov_scale: float | None = None
    lc_min_std: tuple[float, float] = (1e-4, 1e-3)
    lc_inflate_max: float | None = 4.0
    imu_noise: bool = True
    frame_gyro_walk: bool = True
    # Opt-in (measured 2026-12-05, ``docs/results/low-rate.md``): GPS-denied on recorded
    # features it is the more accurate (EuRoC V1_01 synthetic every frame 0.037 -> 0.020 m,
    # simulated flights 2 Hz 0.056 -> 0.029 m, 0.5 Hz 0.425 -> 0.272 m, village 5 Hz 10 seeds
    # 0.093 -> 0.071 m, NEES 11.5 -> 9.7), but the k-1 pixels it fuses again have already moved
    # the clone they are measured against, a correlation the factor 2 does not model: on a
    # GPS-aided village flight with a 10 s outage (``tests/test_smoothing.py``) the forward ATE
    # goes 0.048 -> 0.059 m and the smoothed one 0.029 -> 0.067 m, worse than the forward run.
    # On images (KITTI raw ``3d`` GPS-denied): final error 1.353 -> 1.169 %, NEES 73.7 -> 89.8.
    # Keeping the information without the correlation needs a window of clones fusing each
    # track once (the MSCKF update).
    shared_pixels: bool = False
    # Every pixel in both frame pairs it belongs to at its full variance, the noise it shares
    # between them followed as a cross-covariance with the state (``filter.noise_correlation``):
    # the information single use leaves out, without the double count shared pixels split.
    # Opt-in (measurements in the docstring): it loses on EuRoC's irregular frames, costs 1.4-1.7x.
    correlated_pixels: bool = False
    single_use_pixels: bool = True
    min_disparity_px: float | None = None
    motion_prior: bool = False
    motion_prior_after_s: float | None = 1.0
    motion_prior_inflation: float = 4.0
    motion_prior_min_std: tuple[float, float] = (2e-3, 5e-3)
    estimate_extrinsics: bool = False
    extrinsics_std_deg: float = 1.0
    consider_extrinsics_std_deg: float | None = None
    estimate_time_offset: bool = False
    time_offset_std_ms: float = 20.0
    update_iterations: int = 1
    two_view: bool = False
    instrument_points: bool = False
    frame_gate_probability: float | None = None
    frame_min_inlier_fraction: float = 0.5
    egomotion_fallback: bool = True
    egomotion_bundle: bool | None = None
    lc_bundle_short: bool = False
    frame_max_nis_per_dof: float | None = 3.0
    iterate_after_s: float | None = 0.3
    long_iterations: int = 6
    two_view_after_long: bool = True
    two_view_fill_far: bool = True
    relocalise: bool = True
    relocalise_min_features: int = 20
    relocalise_min_drift: float = 2.5
    relocalise_inflation: float = 1.5
    keyframe_spacing_s: float = 1.0
    max_keyframes: int = 500

    def __post_init__(self) -> None:
        check_types(self, "vision.")
        if self.relocalise_min_features < 3 or self.max_keyframes < 1:
            raise ConfigError(
                "vision.relocalise_min_features must be >= 3 and vision.max_keyframes >= 1, "
                f"got {self.relocalise_min_features} and {self.max_keyframes}")
        if not (self.relocalise_inflation >= 1 and self.relocalise_min_drift > 2
                and self.keyframe_spacing_s >= 0):  # fmt: skip
            raise ConfigError(
                "vision.relocalise_inflation must be >= 1, vision.relocalise_min_drift > 2 and "
                f"vision.keyframe_spacing_s >= 0, got {self.relocalise_inflation}, "
                f"{self.relocalise_min_drift} and {self.keyframe_spacing_s}")
        if self.long_iterations < 1:
            raise ConfigError(f"vision.long_iterations must be >= 1, got {self.long_iterations}")
        if self.update_iterations < 1:
            raise ConfigError(
                f"vision.update_iterations must be >= 1, got {self.update_iterations}"
            )
        if self.rotation not in MOTION_MODELS:
            raise ConfigError(
                f"vision.rotation must be one of {MOTION_MODELS}, got {self.rotation!r}"
            )
        if self.source not in ("auto", "features", "images"):
            raise ConfigError(
                f"vision.source must be auto, features or images, got {self.source!r}"
            )
        if self.frame_stride < 1:
            raise ConfigError(f"vision.frame_stride must be >= 1, got {self.frame_stride}")
        if self.estimate_extrinsics and self.rotation != "clone":
            raise ConfigError(
                "vision.estimate_extrinsics needs vision.rotation=clone (the camera rotation "
                f"is estimated against the cloned pose), got {self.rotation!r}"
            )
        if self.shared_pixels and self.correlated_pixels:
            raise ConfigError(
                "vision.shared_pixels and vision.correlated_pixels are two ways of fusing a "
                "pixel in both frame pairs: choose one"
            )
        if self.two_view and (self.rotation != "clone" or not (
                self.single_use_pixels or self.shared_pixels or self.correlated_pixels)):
            raise ConfigError(
                "vision.two_view needs vision.rotation=clone and vision.shared_pixels=true or "
                "vision.single_use_pixels=true (it fuses the k-1 pixels themselves, which are "
                f"then split or unfused), got rotation {self.rotation!r}, shared_pixels "
                f"{self.shared_pixels}, single_use_pixels {self.single_use_pixels}"
            )
        if self.short_gap_s is not None and not self.short_gap_s >= 0:
            raise ConfigError(f"vision.short_gap_s must be >= 0 s or null, got {self.short_gap_s}")
        for name in ("max_features", "max_features_short"):
            n = getattr(self, name)
            if n is not None and n < 1:
                raise ConfigError(f"vision.{name} must be >= 1 or null (all), got {n}")
        if self.lc_inflate_max is not None and not self.lc_inflate_max >= 1:
            raise ConfigError("vision.lc_inflate_max must be >= 1 (times the gate) or null "
                              f"(refuse every egomotion above the gate), got "
                              f"{self.lc_inflate_max}")  # fmt: skip
        if not 0 <= self.frame_min_inlier_fraction <= 1:
            raise ConfigError("vision.frame_min_inlier_fraction must be in [0, 1], got "
                              f"{self.frame_min_inlier_fraction}")  # fmt: skip
        if self.frame_gate_probability is not None and not 0 < self.frame_gate_probability < 1:
            raise ConfigError("vision.frame_gate_probability must be in (0, 1) or null, got "
                              f"{self.frame_gate_probability}")  # fmt: skip
        con = self.consider_extrinsics_std_deg
        if con is not None and not (con > 0 and self.rotation == "clone"
                                    and not self.estimate_extrinsics):  # fmt: skip
            raise ConfigError(
                "vision.consider_extrinsics_std_deg must be positive, with vision.rotation=clone "
                "and without vision.estimate_extrinsics (the rotation is either estimated or "
                f"considered), got {con} with rotation {self.rotation!r} and estimate_extrinsics "
                f"{self.estimate_extrinsics}")
        if con is not None and self.correlated_pixels:
            # the noise's correlation follows full updates only (filter.noise_correlation)
            raise ConfigError("vision.consider_extrinsics_std_deg does not go with "
                              "vision.correlated_pixels yet: the pixels' correlation cannot be "
                              "followed through an update that keeps a considered block; drop "
                              "one of the two")
        if not self.extrinsics_std_deg > 0:
            raise ConfigError(
                f"vision.extrinsics_std_deg must be positive, got {self.extrinsics_std_deg}"
            )
        if self.estimate_time_offset and self.rotation != "clone":
            raise ConfigError(
                "vision.estimate_time_offset needs vision.rotation=clone (the offset shifts the "
                f"cloned pose and the current one alike), got {self.rotation!r}"
            )
        if not (math.isfinite(self.time_offset_std_ms) and self.time_offset_std_ms > 0):
            raise ConfigError("vision.time_offset_std_ms must be positive and finite (ms), got "
                              f"{self.time_offset_std_ms}")  # fmt: skip

    def noise_scale(self) -> float:
        """``pixel_noise_scale``, or its default: 1 with clones (the relative motion is exact),
        2 for the models that approximate it (measured, see ``bench/tc_noise_scan.py``)."""
        if self.pixel_noise_scale is not None:
            return float(self.pixel_noise_scale)
        return 1.0 if self.rotation == "clone" else 2.0

    def min_disparity(self, sigma_px: float, noise_known: bool = True,
                      shared: bool = False) -> float:
        """``min_disparity_px``, or its default: none with ``shared`` pixels (every frame is a
        two-view frame, see ``two_view_fill_far``), else 12 pixel-noise standard deviations with
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
        if self.rotation != "clone" or not noise_known or shared:
            return 0.0  # shared pixels: two-view frames, whose inverse-depth points need none
        return 12.0 * sigma_px

    def bundle_for(self, method: str) -> bool:
        """Whether ``method``'s egomotions on pre-tracked features are refined by the two-frame
        bundle adjustment (``frontend.egomotion_bundle``): ``egomotion_bundle``, or by default
        for ``vo`` only.

        Why not by default for ``lc`` and the ``tc``/``3d`` fallback (measured 2026-12-03,
        EuRoC V1_01 real IMU, features0 simulated at 5 Hz, GPS-denied, ``--set
        vision.frame_stride=S``): the refined egomotion is 5-20x more precise and consistent
        (NEES 6.6 / 7.8 for 6 dof at S=10 / 25), and ``lc`` gains at 0.2 s spacing (ATE
        0.114 → 0.015 m, NEES 4.9), but across 2-5 s the real IMU's own prediction is
        overconfident (the filter's velocity NEES 3.5-6 for 3 dof), so a precise egomotion is
        refused by the gate or pulls the state too hard: ``lc`` S=10 0.120 → 0.311 m
        (7 frames refused; 0.070 m with no gate), S=25 1.42 → 4.15 m; ``3d`` with the refined
        fallback S=10 0.098 → 0.355 m, S=25 0.861 → 2.05 m. ``vo`` has no IMU to contradict:
        S=1 / S=10 0.0069 / 0.0153 m."""
        if self.egomotion_bundle is not None:
            return bool(self.egomotion_bundle)
        return method == "vo"

    def bundle_max_gap_for(self, method: str) -> float | None:
        """The longest frame gap (s) at which ``method``'s egomotions are refined by the
        bundle adjustment although ``bundle_for`` is false (None: never): ``short_gap_s`` for
        ``lc`` with ``lc_bundle_short`` when ``egomotion_bundle`` is None.

        Over short gaps the IMU's prediction is honest and the precise egomotion wins; over
        seconds on a real MAV IMU it does not (see ``bundle_for``). Recorded features only: on
        images the bundle's covariance, from the residuals, misses the front end's errors
        shared across features (KITTI raw ``lc`` GPS-denied NEES 51 → 464, ATE 0.276 → 0.332
        m), so image-based ``lc`` keeps RANSAC's. Measured 2026-12-05 with 1 s and
        ``LC_COV_SCALE_BUNDLE`` 2 (before: RANSAC's egomotion at every gap), ``lc``: EuRoC
        V1_01 synthetic 5 Hz (``bench/low_rate.py``) every frame (0.2 s) 0.114 → 0.017 m,
        every 10th / 25th frame unchanged (0.120 / 0.569 m); irregular frames 0.05-7 s
        (``bench/irregular_frames.py``) 0.329 → 0.321 m; simulated flights 2 Hz 0.219 → 0.037
        m, 0.5 Hz unchanged; the village 5 Hz, 10 seeds (``bench/paper_ordering.py``) 0.309 →
        0.070 m, NEES 7.86 → 11.0 (inside the 95 % band, 14.1 with factor 1). Opt-in: with
        it ``lc`` passes the default ``3d`` (2 Hz flights 0.037 against 0.056 m, village 0.070
        against 0.093 m), the paper's ordering reversed; with ``shared_pixels`` too ``3d``
        leads again at 2 Hz (0.029 m), at costs of its own (see the comment at the
        ``shared_pixels`` field)."""
        if method != "lc" or self.egomotion_bundle is not None or not self.lc_bundle_short:
            return None
        return self.short_gap_s

    def is_short(self, gap_s: float) -> bool:
        """Whether a frame ``gap_s`` s after its reference is short (``short_gap_s``)."""
        return self.short_gap_s is not None and gap_s <= self.short_gap_s

    def features_for_gap(self, gap_s: float) -> int | None:
        """The most features a ``tc``/``3d`` frame ``gap_s`` s after its reference fuses:
        the larger of ``max_features_short`` and ``max_features`` when the gap is short
        (``short_gap_s``), else ``max_features`` (None: all).

        A short frame's prior is narrow and its pixels near-linear in the state: each feature
        adds information. Across a long gap the sigma points span metres and the real IMU's
        prediction is overconfident, so many precise features pull a wide prior too hard.
        Measured 2026-12-05 with shared pixels, 300 against 120 in every frame: EuRoC V1_01
        synthetic 5 Hz every frame 0.038 → 0.020 m; simulated flights at 2 Hz 0.043 → 0.029 m;
        at 0.5 Hz 0.272 → 0.651 m (V1_02 seed 2: 0.32 → 3.99 m) and EuRoC irregular frames
        0.308 → 0.326 m, where 300 in short frames only gives 0.272 and 0.304 m."""
        if not self.is_short(gap_s) or self.max_features is None:
            return self.max_features
        if self.max_features_short is None:
            return None
        return max(self.max_features, self.max_features_short)

    def lc_scale(self, estimator: str = "forward") -> float:
        """``lc_cov_scale``, or its default for an egomotion from ``estimator``: ``"bundle"``
        ``LC_COV_SCALE_BUNDLE``, ``"forward"`` (RANSAC's) ``LC_COV_SCALE``, with clones too.

        Why the forward estimate needs 30: the clone puts the
        egomotion's correlation with the state at k-1 in the model, but not the correlation
        between consecutive egomotions (both use the k-1 pixels) nor the front end's own
        overconfidence on features0 (raw NEES 18-29 for 6 dof). Measured with clones, factor 1
        against 30: village 60 s seeds 0-2, ATE 0.415/0.310/0.501 m against 0.404/0.282/0.271,
        NEES 88/84/42 against 8.1/6.7/7.2; KITTI raw GPS-denied, final error 1.93 % (62 of 179
        frames rejected by the gate) against 1.39 %."""
        if self.lc_cov_scale is not None:
            return float(self.lc_cov_scale)
        return LC_COV_SCALE_BUNDLE if estimator == "bundle" else LC_COV_SCALE
