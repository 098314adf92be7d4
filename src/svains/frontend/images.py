"""Input image checks of the front end: grey conversion and a cheap texture measure."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]


def image_problem(img: object, shape: tuple[int, int] | None) -> str | None:
    """Why ``as_grey`` refuses ``img`` (missing, not 2-D grey or 3/4-channel colour, or not
    ``shape`` (H, W)), or None."""
    if img is None:
        return "missing"
    a = np.asarray(img)
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))) or a.size == 0:
        return f"an array of shape {a.shape} is no image"
    if shape is not None and a.shape[:2] != shape:
        return f"image is {a.shape[1]}x{a.shape[0]} px, the calibration's {shape[1]}x{shape[0]}"
    return None


def as_grey(img: object, shape: tuple[int, int] | None) -> U8 | None:
    """uint8 (H, W) image, or None for a missing/malformed/wrong-size image
    (``image_problem``)."""
    if image_problem(img, shape) is not None:
        return None
    a = np.asarray(img)
    if a.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        a = cv2.cvtColor(np.clip(a, 0, 255).astype(np.uint8), code)
    if a.dtype != np.uint8:
        if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
            return None
        a = np.clip(a, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(a)


def texture_std(img: U8) -> float:
    """Standard deviation of grey levels of ``img`` (H, W) on a 4x subsampled grid."""
    return float(cv2.meanStdDev(np.ascontiguousarray(img[::4, ::4]))[1][0, 0])
