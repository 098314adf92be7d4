"""Does the stereo calibration fit the images? Left and right swapped, rows that do not agree.

A rig's left and right streams are easily crossed (two cables, two topics, ``cam0``/``cam1``
folders written the other way round). The run then goes on without a word: every left-right
match the front end looks for has its disparity on the wrong side, nothing is tracked, and the
filter coasts on the IMU (KITTI raw with the two image folders swapped: 170 % of the path off,
one frame of 180 fused, and only "no vision fused for 2.0 s" to say so).

The test: corners of the rectified left image tracked into the rectified right image by KLT
(pyramid deep enough for 150 px, forward-backward checked), free in both directions. In a
right pair a point's right pixel lies left of its left pixel (disparity ``u_L - u_R > 0``) on
the same row; with the streams swapped nearly every match lies the other way (shared data,
5 pairs each: KITTI raw, KITTI odometry, EuRoC and the rendered village 0-2 negative of
700-1900 matches; KITTI raw swapped 1068 of 1068 negative, rows 9-13 px apart). Matches with
``|disparity| < 1`` px (points at infinity) say nothing and are left out. The median row offset
of the matches is kept too: a few pixels mean rectification does not fit the images (a wrong
``T_BS`` between the cameras, intrinsics of another camera).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.frontend.features import DetectorOptions, detect_corners
from svains.frontend.tracking import KltOptions, Pyramid, track_klt

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

# KLT reach for the check: 2^5 levels x 10 px capture covers the largest disparities of a wide
# baseline (KITTI: up to ~130 px) without a row-search start.
_KLT = KltOptions(win_px=21, levels=5)
MIN_MATCHES = 60  # matches before a verdict (both ways)
MIN_PAIRS = 3  # pairs before a verdict: one view of a fence or a shop window could mislead
SWAPPED_FRACTION = 0.8  # of the matches at negative disparity: swapped
ROW_OFFSET_WARN_PX = 3.0  # median |v_L - v_R| above which rectification does not fit
# Of the matches at negative disparity, short of a swap: a lens model that does not fit (a
# fisheye lens declared radial-tangential, KITTI raw's images: 3.8-14.8 % of 660-1100 matches,
# the run 17x its error, without a word: a user's probe) or cam1 turned on cam0 about the
# image's vertical (KITTI raw, 0.4°: 2.5 % over the drive, 3 % or more in 62 of 178 windows
# of 3 pairs, 44 m off; a review); right calibrations leave 0-0.3 % (shared data, rendered
# village; at most 0.53 % in any window of 3 pairs)
PARTLY_NEGATIVE_FRACTION = 0.03
# the rows of the pairs rectified with the two images exchanged fit this well for crossed
# streams (EuRoC: 0.1 px); cam1's T_BS 3° off about x left 2.5 px exchanged, not a swap
SWAPPED_ROWS_FIT_PX = 1.0


@dataclass
class StereoCheck:
    """Left-right matches pooled over stereo pairs: ``pairs`` looked at, ``matches`` kept
    (``|disparity| >= 1`` px), ``negative`` of them at negative disparity, and the row offsets
    ``|v_L - v_R|`` (px) of all of them (``rows``)."""

    pairs: int = 0
    matches: int = 0
    negative: int = 0
    rows: F64 | None = None
    # the median row offset (px) of the same pairs with the raw images swapped before
    # rectification, where the rows as given did not fit (None: not looked at)
    swapped_rows_px: float | None = None
    rechecks: int = 0  # looks again after frames without a motion (``pipeline._watch_stereo``)
    exchanges: int = 0  # streams crossed mid-run and exchanged back (``pipeline._check_stereo``)

    def add_pair(self, left: U8, right: U8, detector: DetectorOptions) -> None:
        """Pool one rectified pair (H, W) uint8."""
        uv = detect_corners(left, np.zeros((0, 2)), detector)
        self.pairs += 1
        if uv.shape[0] == 0:
            return
        uv_r, ok = track_klt(Pyramid(left, _KLT), Pyramid(right, _KLT), uv, _KLT)
        d = uv[ok, 0] - uv_r[ok, 0]
        dv = np.abs(uv[ok, 1] - uv_r[ok, 1])
        seen = np.abs(d) >= 1.0
        self.matches += int(seen.sum())
        self.negative += int((d[seen] < 0).sum())
        self.rows = dv[seen] if self.rows is None else np.concatenate([self.rows, dv[seen]])

    @property
    def decided(self) -> bool:
        return self.pairs >= MIN_PAIRS and self.matches >= MIN_MATCHES

    @property
    def negative_fraction(self) -> float:
        return self.negative / self.matches if self.matches else float("nan")

    @property
    def row_offset_px(self) -> float:
        """Median row offset (px) of the matches (NaN without any)."""
        if self.rows is None or self.rows.size == 0:
            return float("nan")
        return float(np.median(self.rows))

    @property
    def swapped(self) -> bool:
        return self.decided and (self.negative_fraction >= SWAPPED_FRACTION
                                 or self.rows_fit_swapped)  # fmt: skip

    @property
    def rows_fit_swapped(self) -> bool:
        """The rows do not fit as given and fit with the raw images swapped (cameras whose
        calibrations differ: EuRoC's streams swapped left rows 25.6 px apart and 4.5 % of the
        matches negative, told only "check T_BS": a user's probe)."""
        return (self.swapped_rows_px is not None and self.row_offset_px > ROW_OFFSET_WARN_PX
                and self.swapped_rows_px <= min(SWAPPED_ROWS_FIT_PX,
                                                0.2 * self.row_offset_px))  # fmt: skip

    def problem(self) -> str | None:
        """One line saying what is wrong with the pair, or None."""
        if self.decided and self.rows_fit_swapped:
            return (f"the left and right images look swapped: rectified as given their "
                    f"left-right matches are {self.row_offset_px:.1f} px apart in rows, with the "
                    f"two images exchanged {self.swapped_rows_px:.1f} px: is the left camera's "
                    "stream in cam1?")  # fmt: skip
        if self.swapped:
            return (f"the left and right images look swapped: {self.negative} of {self.matches} "
                    "left-right matches lie at negative disparity (the right pixel right of the "
                    "left one): is the left camera's stream in cam1?")  # fmt: skip
        if self.decided and self.row_offset_px > ROW_OFFSET_WARN_PX:
            return (f"rectification does not fit the images: left-right matches are "
                    f"{self.row_offset_px:.1f} px apart in rows (median of {self.matches}); "
                    "check the cameras' T_BS and intrinsics")  # fmt: skip
        if self.decided and self.negative_fraction >= PARTLY_NEGATIVE_FRACTION:
            return (f"{self.negative} of {self.matches} left-right matches lie at negative "
                    f"disparity (rows {self.row_offset_px:.1f} px apart): does the lens model "
                    "fit the cameras (distortion_model, its coefficients, the intrinsics), and "
                    "is cam1's rotation on cam0 right (its T_BS; a turn about the image's "
                    "vertical shifts every disparity)? A fisheye lens read as "
                    "radial-tangential, or cam1 turned 0.4° more than its T_BS says, does "
                    "this")  # fmt: skip
        return None

    def summary(self) -> dict[str, float | int]:
        """For ``report.json``."""
        out: dict[str, float | int] = {"pairs": self.pairs, "matches": self.matches,
                                       "negative_fraction": self.negative_fraction,
                                       "row_offset_px": self.row_offset_px}  # fmt: skip
        if self.swapped_rows_px is not None:
            out["swapped_row_offset_px"] = self.swapped_rows_px
        if self.rechecks:
            out["rechecks"] = self.rechecks
        if self.exchanges:
            out["exchanges"] = self.exchanges
        return out


def check_pairs(pairs: list[tuple[U8, U8]], detector: DetectorOptions | None = None) -> StereoCheck:
    """The check over rectified pairs (each (H, W) uint8 left, right)."""
    det = detector if detector is not None else DetectorOptions()
    check = StereoCheck()
    for left, right in pairs:
        check.add_pair(left, right, det)
    return check

