"""Grey image decode/encode: the only place in ``svains.datasets`` that touches OpenCV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.errors import DatasetError


def read_grey(path: Path) -> NDArray[np.uint8]:
    """Decode an image file as 8-bit grey (H, W); DatasetError naming the file if unreadable."""
    import cv2  # imported lazily: reading calibration/CSV never needs OpenCV

    from svains.datasets.validate import image_file_problem

    # A file cut short is named here, before the decoder prints its own lines on stderr
    # (libpng: "Read Error") that a user cannot tell from a crash.
    problem = image_file_problem(path)
    if problem is not None:
        raise DatasetError(f"unreadable image: {path}: {problem}")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise DatasetError(f"unreadable image: {path}")
    return img


def write_grey(path: Path, image: NDArray[np.uint8]) -> None:
    """Encode an 8-bit grey (H, W) image to ``path`` (format from the suffix, PNG lossless).

    PNG is stored without deflate, as EuRoC stores its images: a rendered 752x480 frame then
    decodes in ~1.4 ms instead of ~3.4 ms (inflate dominates), at about twice the file size.
    A 20 Hz stereo replay decodes 40 images per second, so this is CPU every reader saves.
    """
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f"expected a uint8 (H, W) image, got {img.dtype} {img.shape}")
    params = [cv2.IMWRITE_PNG_COMPRESSION, 0] if Path(path).suffix.lower() == ".png" else []
    if not cv2.imwrite(str(path), img, params):
        raise DatasetError(f"could not write image: {path}")


def decode_raw(encoding: str, height: int, width: int, step: int, data: bytes) -> NDArray[np.uint8]:
    """A ROS ``sensor_msgs/Image`` buffer as 8-bit grey (H, W): mono8/16 and 8-bit colour.

    16-bit images keep their 8 most significant bits; colour is converted with OpenCV's weights.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    enc = encoding.lower()
    if enc in ("mono8", "8uc1"):
        return buf.reshape(height, step)[:, :width].copy()
    if enc in ("mono16", "16uc1"):
        return (buf.view("<u2").reshape(height, step // 2)[:, :width] >> 8).astype(np.uint8)
    codes = {"bgr8": (3, "COLOR_BGR2GRAY"), "rgb8": (3, "COLOR_RGB2GRAY"),
             "bgra8": (4, "COLOR_BGRA2GRAY"), "rgba8": (4, "COLOR_RGBA2GRAY")}  # fmt: skip
    if enc not in codes:
        raise DatasetError(f"image encoding {encoding!r} is not supported (mono8/16, bgr8, rgb8)")
    import cv2

    ch, code = codes[enc]
    img = buf.reshape(height, step)[:, : width * ch].reshape(height, width, ch)
    return cv2.cvtColor(np.ascontiguousarray(img), getattr(cv2, code))


def decode_compressed(data: bytes) -> NDArray[np.uint8]:
    """A ROS ``sensor_msgs/CompressedImage`` (PNG/JPEG bytes) as 8-bit grey (H, W)."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise DatasetError("undecodable compressed image message")
    return img
