"""Row search of the left-right match: windows cut without padding the images, and the search
itself on a synthetic pair with a known disparity."""

from __future__ import annotations

import cv2
import numpy as np

from svains.frontend.stereo import _windows, block_match_rows


def _texture(seed: int, shape: tuple[int, int] = (120, 300)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, shape).astype(np.uint8)
    return cv2.GaussianBlur(img, (3, 3), 0.8)


def test_windows_equal_those_of_the_edge_replicated_image() -> None:
    """Inside, on and beyond every edge: the same pixels as a window of the image padded by
    edge replication (what the search compares)."""
    img = _texture(0)
    h, w = img.shape
    half, before = 5, 40
    row = np.array([60, 0, h - 1, 3, 60, 60, 60, -4, h + 2])
    col = np.array([150, 150, 150, 150, 0, w - 1, 41, 10, w + 3])
    pad = cv2.copyMakeBorder(img, half + 10, half + 10, before + 10, half + 10,
                             cv2.BORDER_REPLICATE)  # fmt: skip
    got = _windows(img, row, col, half, before)
    for i, (r, c) in enumerate(zip(row, col, strict=True)):
        r0, c0 = r + 10, c + 10  # window's top-left corner in the padded image
        ref = pad[r0 : r0 + 2 * half + 1, c0 : c0 + before + half + 1]
        np.testing.assert_array_equal(got[i], ref)


def test_row_search_finds_the_disparity_up_to_the_left_edge() -> None:
    """A right image shifted by 17 px: every textured corner, also within the search range of
    the left edge, gets disparity 17 and is valid; a corner whose match would lie left of the
    right image is not."""
    left = _texture(1)
    right = np.empty_like(left)
    right[:, :-17] = left[:, 17:]
    right[:, -17:] = left[:, -17:]
    uv = np.array([[150.0, 60.0], [40.0, 30.0], [20.0, 90.0], [280.0, 100.0], [10.0, 60.0]])
    disp, ok = block_match_rows(left, right, uv, 64.0)
    np.testing.assert_array_equal(disp[:4], 17.0)
    assert ok[:4].all()
    assert not ok[4]  # 10 - 17 < 0: the match would be off the right image
