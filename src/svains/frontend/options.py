"""Settings and per-frame statistics of the stereo front end (``frontend.pipeline``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from svains.frontend.egomotion import RansacOptions
from svains.frontend.features import DetectorOptions
from svains.frontend.reacquire import ReacquireOptions
from svains.frontend.stereo import StereoMatchOptions
from svains.frontend.tracking import KltOptions


@dataclass(frozen=True)
class FrontendOptions:
    """All front-end settings. ``min_texture_std`` grey levels below which a frame is treated as
    textureless; ``epipolar_final_px`` row tolerance of the final inlier check (both times);
    ``prior_gate_chi2`` Mahalanobis gate of the estimate against a given motion prior;
    ``max_translation_m``/``max_rotation_deg`` plausibility limits per frame (None: no limit);
    ``max_hold_frames`` consecutive rejected frames (motion contradicting the prior, implausible)
    for which the reference frame is kept before the front end re-initialises on the new view;
    ``predict_tracks`` starts KLT where the last motion (or the prior) predicts each feature;
    ``retry_failed_after`` frames during which a new corner that found no left-right match is
    not proposed again (edges and occlusions otherwise cost a row search every frame), as long
    as the image is nearly still (median feature flow below ``retry_max_flow_px``; with larger
    motion the remembered places no longer mean anything); new corners are sought only once
    more than ``redetect_lost_fraction`` of the features kept after the last search are lost,
    or ``redetect_every`` frames after it (a still or slow camera keeps its tracks, and each
    search costs a detection, a row search and a left-right KLT pass);
    ``min_inlier_fraction`` of the matched features must be RANSAC inliers for a motion
    measurement (a small consensus among many tracks is more often a wrong motion, e.g. a
    repeated texture, than a scene mostly moving); ``retry_levels`` pyramid levels of a second,
    unpredicted temporal KLT pass when the predicted tracks gave no consensus (at the onset of a
    sharp turn the constant-velocity prediction is far off: 2 Hz village flight, t = 35 s);
    ``reacquire``: descriptor matching when KLT still gave no consensus (long gaps, low frame
    rates; ``frontend.reacquire``); ``bundle``: refine the RANSAC egomotion by the two-frame
    bundle adjustment (``frontend.egomotion_bundle``) on the features that pass the epipolar
    check."""

    detector: DetectorOptions = field(default_factory=DetectorOptions)
    klt: KltOptions = field(default_factory=KltOptions)
    stereo: StereoMatchOptions = field(default_factory=StereoMatchOptions)
    ransac: RansacOptions = field(default_factory=RansacOptions)
    reacquire: ReacquireOptions = field(default_factory=ReacquireOptions)
    min_texture_std: float = 3.0
    epipolar_final_px: float = 1.0
    prior_gate_chi2: float = 50.0
    max_translation_m: float | None = None
    max_rotation_deg: float | None = None
    max_hold_frames: int = 3
    predict_tracks: bool = True
    retry_failed_after: int = 3
    retry_max_flow_px: float = 2.0
    redetect_lost_fraction: float = 0.05
    redetect_every: int = 5
    min_inlier_fraction: float = 0.3
    retry_levels: int = 4
    bundle: bool = False


HOLD_STATUSES = ("contradicts_prior", "implausible")


@dataclass
class FrameStats:
    """Counts and per-stage timings (ms) of the last processed frame."""

    t_ns: int = 0
    status: str = ""
    tracked: int = 0
    new: int = 0
    inliers: int = 0
    outliers: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
