"""Pyramidal Lucas-Kanade tracking with a forward-backward consistency check."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]


@dataclass(frozen=True)
class KltOptions:
    """KLT settings: window ``win_px`` (odd), ``levels`` pyramid levels above the base,
    ``levels_predicted`` when the start is predicted (motion prior or constant velocity; fewer
    levels are cheaper, but at the onset of a turn the prediction is off by more than two levels
    can recover: 2 lost the egomotion on a sharp turn of the simulated village flight),
    ``fb_levels`` for the backward check (it starts where the feature came from, so a consistent
    track needs no coarse level), forward-backward error limit ``fb_max_px``, termination
    ``iterations``/``epsilon``; ``fb_when_predicted=False`` skips the backward pass when the
    start was predicted from a motion (RANSAC against that motion and the epipolar checks then
    guard the tracks, and one of the front end's four KLT passes is saved).

    ``adaptive_levels``: when the start is predicted (motion prior or constant velocity), the
    levels follow how far the previous predicted frame's tracks ended from their predicted
    starts (90th percentile ``r`` px, ``pipeline.StereoFrontend``): the fewest levels ``L``
    whose reach ``capture_px * 2^L`` covers ``residual_margin * r``, at most
    ``levels_predicted``. The prediction error changes slowly from frame to frame; each level
    costs a pyramid and a search per feature (20 Hz simulated bench flight: 1 level on 270 of
    400 frames, 2 on 126, temporal KLT 0.4 ms less per frame; KITTI raw at 5 Hz keeps 3 on 163
    of 178). Reach measured on the simulated village and KITTI images: 99 % of starts offset
    by 1 px converge to the full-pyramid track at level 0, by 4 px at one level, by 8 px at
    two, by 16 px at three. A frame whose prediction is far off (the onset of a turn) loses
    its tracks and gets the unpredicted retry (``FrontendOptions.retry_levels``), after which
    the next frame has all levels again. With few levels a track that drifts over a region
    turned blank is not lost by KLT but at the left-right match (one frame later for the
    corner search)."""

    win_px: int = 11
    levels: int = 3
    levels_predicted: int = 3
    fb_levels: int = 1
    fb_max_px: float = 0.5
    iterations: int = 30
    epsilon: float = 0.01
    fb_when_predicted: bool = False
    adaptive_levels: bool = True
    capture_px: float = 2.0
    residual_margin: float = 1.5


def levels_for_residual(residual_px: float, opts: KltOptions) -> int:
    """Pyramid levels above the base for a start expected within ``residual_px`` of the
    answer (``KltOptions.adaptive_levels``): the fewest ``L`` with
    ``residual_margin * residual_px <= capture_px * 2^L``, at most ``levels_predicted``."""
    need = opts.residual_margin * residual_px / opts.capture_px
    if not np.isfinite(need):
        return opts.levels_predicted
    if need <= 1.0:
        return 0
    return min(int(np.ceil(np.log2(need))), opts.levels_predicted)


def _pyramid_input_supported() -> bool:
    """OpenCV 4 takes prebuilt pyramids in ``calcOpticalFlowPyrLK``; the OpenCV 5.0 Python binding
    does not: it rejects the pyramid as a tuple, a list or a list of ``UMat``, built with or
    without derivatives and with the call's own window and level count (checked 2026-11). The
    front end therefore keeps KLT calls few and cheap instead (see ``KltOptions``)."""
    img = np.zeros((64, 64), np.uint8)
    try:
        _, pyr = cv2.buildOpticalFlowPyramid(img, (9, 9), 1, withDerivatives=True)
        cv2.calcOpticalFlowPyrLK(
            pyr, pyr, np.zeros((1, 1, 2), np.float32), None, winSize=(9, 9), maxLevel=1
        )
    except cv2.error:
        return False
    return True


_PYRAMIDS = _pyramid_input_supported()


class Pyramid:
    """An image pyramid built once and reused by every KLT call on that image (where the OpenCV
    binding allows it; otherwise the image itself, and OpenCV builds the pyramid per call)."""

    def __init__(self, img: U8, opts: KltOptions) -> None:
        self.image = img
        if _PYRAMIDS:
            self.levels, self.pyr = cv2.buildOpticalFlowPyramid(
                img, (opts.win_px, opts.win_px), opts.levels, withDerivatives=True
            )
        else:
            self.levels, self.pyr = opts.levels, img


def _lk(
    src: Pyramid, dst: Pyramid, uv: F64, guess: F64 | None, opts: KltOptions, max_level: int
) -> tuple[F64, Bool]:
    """One LK pass ``src`` -> ``dst`` of ``uv`` (N, 2): positions (N, 2) and status (N,)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, opts.iterations, opts.epsilon)
    p0 = uv.astype(np.float32).reshape(-1, 1, 2)
    flags = 0
    p1 = None
    if guess is not None:
        p1 = guess.astype(np.float32).reshape(-1, 1, 2).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, status, _ = cv2.calcOpticalFlowPyrLK(
        src.pyr, dst.pyr, p0, p1, winSize=(opts.win_px, opts.win_px),
        maxLevel=min(src.levels, dst.levels, max_level), criteria=crit, flags=flags,
    )
    out = p1.reshape(-1, 2).astype(float)
    ok = status.reshape(-1).astype(bool) & np.all(np.isfinite(out), axis=1)
    return out, ok


def track_klt(
    src: Pyramid, dst: Pyramid, uv: F64, opts: KltOptions, guess: F64 | None = None,
    max_level: int | None = None, fb_check: bool = True, fb_max_level: int | None = None,
) -> tuple[F64, Bool]:
    """Track ``uv`` (N, 2) px from ``src`` into ``dst``; a point survives if both passes succeed,
    it stays in the image, and tracking back lands within ``opts.fb_max_px`` of where it started.

    ``fb_check=False`` skips the backward pass (when other checks guard the match).
    ``max_level`` caps the pyramid levels (a good ``guess`` needs few; coarse levels can jump to
    another repetition of a periodic texture); ``fb_max_level`` caps those of the backward pass
    (default: as the forward one). Returns tracked pixels (N, 2) and validity (N,).
    """
    lv = opts.levels if max_level is None else max_level
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    if uv.shape[0] == 0:
        return uv.copy(), np.zeros(0, dtype=bool)
    fwd, ok_f = _lk(src, dst, uv, guess, opts, lv)
    h, w = dst.image.shape[:2]
    inside = (fwd[:, 0] >= 0) & (fwd[:, 1] >= 0) & (fwd[:, 0] <= w - 1) & (fwd[:, 1] <= h - 1)
    if not fb_check:
        return fwd, ok_f & inside
    back, ok_b = _lk(dst, src, fwd, uv, opts, lv if fb_max_level is None else fb_max_level)
    fb = np.linalg.norm(back - uv, axis=1)
    return fwd, ok_f & ok_b & inside & (fb <= opts.fb_max_px)
