"""Grey image decode/encode: the only place in ``svains.datasets`` that touches OpenCV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.errors import DatasetError


def read_grey(path: Path) -> NDArray[np.uint8]:
    """Decode an image file as 8-bit grey (H, W); DatasetError naming the file if unreadable."""
    import cv2  # imported lazily: reading calibration/CSV never needs OpenCV

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise DatasetError(f"unreadable image: {path}")
    return img


def write_grey(path: Path, image: NDArray[np.uint8]) -> None:
    """Encode an 8-bit grey (H, W) image to ``path`` (format from the suffix, PNG lossless)."""
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f"expected a uint8 (H, W) image, got {img.dtype} {img.shape}")
    if not cv2.imwrite(str(path), img):
        raise DatasetError(f"could not write image: {path}")
