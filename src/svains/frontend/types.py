"""What the front end hands to the filter for one new stereo frame (no OpenCV here).

Both the image front end and the ``features0`` reader produce ``StereoTracks``, so navigation code
does not care where tracks came from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Egomotion:
    """Frame-to-frame camera motion ``T_Ck_Ckm1``: ``p_Ck = R_Ck_Ckm1 p_Ckm1 + p_Ck_Ckm1``.

    ``cov`` (6, 6) over (rotation vector of ``R_Ck_Ckm1`` [rad], ``p_Ck_Ckm1`` [m]).
    The rotation error is local, ``R_Ck_Ckm1 = R̂ Exp(δθ)`` (docs/conventions.md).
    ``estimator``: ``"forward"`` (RANSAC on the points triangulated at k-1, taken as exact) or
    ``"bundle"`` (fitted with the points to all four pixels, ``frontend.egomotion_bundle``);
    the fusion scales a forward estimate's covariance (``VisionOptions.lc_scale``).
    """

    R_Ck_Ckm1: F64
    p_Ck_Ckm1: F64
    cov: F64
    estimator: str = "forward"


@dataclass(frozen=True)
class StereoTracks:
    """Features tracked from frame k-1 to frame k in a rectified stereo pair (M features).

    ``uv_left_prev``, ``uv_right_prev``, ``uv_left``, ``uv_right`` (M, 2) px; ``p_Ckm1_F`` (M, 3) m,
    triangulated at k-1 (eq. 10); ``track_id`` (M,); ``inlier`` (M,) bool after RANSAC and the
    epipolar check. ``egomotion`` is ``None`` when the frame gives no motion measurement.
    """

    t_prev_ns: int
    t_ns: int
    track_id: NDArray[np.int64]
    uv_left_prev: F64
    uv_right_prev: F64
    uv_left: F64
    uv_right: F64
    p_Ckm1_F: F64
    inlier: NDArray[np.bool_]
    egomotion: Egomotion | None

    @property
    def has_motion(self) -> bool:
        return self.egomotion is not None and bool(self.inlier.any())
