"""KITTI raw (real, unrectified, 5 distortion coefficients): reading and rectification."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.frontend.rectify import StereoRectifier

F64 = NDArray[np.float64]


def test_reads_five_coefficients_and_rectifies(kitti_raw: Path) -> None:
    ds = load_dataset(kitti_raw)
    assert ds.cam0 is not None and ds.cam1 is not None and ds.left is not None
    np.testing.assert_array_equal(
        ds.cam0.distortion, [-0.3728755, 0.2037299, 0.002219027, 0.001383707, -0.07233722]
    )
    assert ds.cam1.distortion.shape == (5,)
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    assert not rect.identity
    assert rect.rig.baseline == pytest.approx(0.5372, abs=5e-4)  # README: 0.537 m along +x
    # Rectified -> raw (closed form, all 5 coefficients) -> rectified (iterative), corners too.
    w, h = rect.rig.width, rect.rig.height
    uv = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, h / 2], [10, h / 2]])
    for right in (False, True):
        back = rect.rectify_points(rect.unrectify_points(uv, right), right)
        np.testing.assert_allclose(back, uv, atol=1e-6)


def _row_offsets(ds: Dataset, rect: StereoRectifier, frame: int) -> tuple[F64, F64]:
    """|v_left - v_right| (px) of raw left-right KLT matches (forward-backward checked) mapped
    through ``rect``, and the raw left column offset from the centre of each match."""
    assert ds.left is not None and ds.right is not None
    left, right = ds.left.load(frame), ds.right.load(frame)
    corners = cv2.goodFeaturesToTrack(left, 800, 0.01, 12)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, winSize=(21, 21),
                                         maxLevel=4)  # fmt: skip
    p0b, st_b, _ = cv2.calcOpticalFlowPyrLK(right, left, p1, None, winSize=(21, 21), maxLevel=4)
    ok = (st[:, 0] == 1) & (st_b[:, 0] == 1)
    ok &= np.linalg.norm((p0b - corners)[:, 0], axis=1) < 0.3
    uv_l = rect.rectify_points(corners[ok, 0])
    uv_r = rect.rectify_points(p1[ok, 0], right=True)
    return np.abs(uv_l[:, 1] - uv_r[:, 1]), np.abs(corners[ok, 0, 0] - left.shape[1] / 2)


def test_real_matches_share_rows_after_rectification(kitti_raw: Path) -> None:
    """Raw left-right matches of real pairs, mapped through the rectification, lie on one row
    (README: median 0.41 px); beyond a third of the width from the centre, where k3 acts, the
    five coefficients do clearly better than four (k3 dropped)."""
    ds = load_dataset(kitti_raw)
    assert ds.cam0 is not None and ds.cam1 is not None
    rect5 = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    rect4 = StereoRectifier.from_calibration(
        replace(ds.cam0, distortion=ds.cam0.distortion[:4]),
        replace(ds.cam1, distortion=ds.cam1.distortion[:4]),
    )
    frames = (30, 90, 150)
    dv5, du = (np.concatenate(a) for a in zip(*(_row_offsets(ds, rect5, k) for k in frames),
                                               strict=True))  # fmt: skip
    dv4 = np.concatenate([_row_offsets(ds, rect4, k)[0] for k in frames])
    outer = du > 0.33 * ds.cam0.resolution[0]
    assert dv5.size > 600 and outer.sum() > 100
    assert np.median(dv5) < 0.6
    assert np.median(dv5[outer]) < 0.8 * np.median(dv4[outer])
