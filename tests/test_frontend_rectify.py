"""Stereo rectification: identity for ideal pairs, exact geometry for the real EuRoC rig."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.types import CameraCalib
from svains.errors import CalibrationError
from svains.frontend.rectify import StereoRectifier, is_already_rectified
from svains.frontend.stereo import StereoMatchOptions, match_sparse
from svains.frontend.tracking import KltOptions, Pyramid


def _ideal_pair(baseline: float = 0.5) -> tuple[CameraCalib, CameraCalib]:
    T0 = np.eye(4)
    T0[:3, 3] = (0.1, -0.2, 0.3)
    T1 = T0.copy()
    T1[:3, 3] += T0[:3, :3] @ np.array([baseline, 0.0, 0.0])
    K = np.array([500.0, 500.0, 320.5, 240.5])
    kw = dict(rate_hz=10.0, resolution=(640, 480), intrinsics=K,
              distortion_model="radial-tangential", distortion=np.zeros(4))  # fmt: skip
    return CameraCalib(name="cam0", T_B_C=T0, **kw), CameraCalib(name="cam1", T_B_C=T1, **kw)


def test_ideal_pair_is_passed_through_exactly() -> None:
    cam0, cam1 = _ideal_pair(0.5)
    assert is_already_rectified(cam0, cam1)
    rect = StereoRectifier.from_calibration(cam0, cam1)
    rig = rect.rig
    assert rect.identity
    assert (rig.f, rig.cu, rig.cv, rig.width, rig.height) == (500.0, 320.5, 240.5, 640, 480)
    assert rig.baseline == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_array_equal(rig.R_B_C, np.eye(3))
    np.testing.assert_array_equal(rig.p_B_C, [0.1, -0.2, 0.3])
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (480, 640), dtype=np.uint8)
    left, right = rect.rectify_pair(img, img[::-1].copy())
    np.testing.assert_array_equal(left, img)
    np.testing.assert_array_equal(right, img[::-1])
    uv = rng.uniform(0, 600, (7, 2))
    np.testing.assert_array_equal(rect.rectify_points(uv), uv)


def test_distorted_pair_is_not_identity() -> None:
    cam0, cam1 = _ideal_pair(0.5)
    cam1 = replace(cam1, distortion=np.array([-0.2, 0.05, 0.0, 0.0]))
    assert not is_already_rectified(cam0, cam1)
    assert not StereoRectifier.from_calibration(cam0, cam1).identity


def test_bad_calibrations_raise() -> None:
    cam0, cam1 = _ideal_pair(0.5)
    with pytest.raises(CalibrationError, match="cam0: distortion model 'omni' is not supported"):
        StereoRectifier.from_calibration(replace(cam0, distortion_model="omni"), cam1)
    with pytest.raises(CalibrationError, match="cam1: radtan distortion needs 4 or 5 coeff"):
        StereoRectifier.from_calibration(cam0, replace(cam1, distortion=np.zeros(6)))
    with pytest.raises(CalibrationError, match="cam0: equidistant distortion needs 4 coeff"):
        bad0 = replace(cam0, distortion_model="equidistant", distortion=np.zeros(5))
        StereoRectifier.from_calibration(bad0, cam1)
    # Right camera on the left: swapped pair.
    with pytest.raises(CalibrationError, match=r"cam1 must be right of cam0 \(along cam0's x "
                       r"axis\), but sits at \[-0\.\d+, -?0\.0, -?0\.0\] m in cam0's frame; "
                       r"cameras swapped"):  # fmt: skip
        bad1 = replace(cam1, distortion=np.array([1e-3, 0, 0, 0]))
        StereoRectifier.from_calibration(bad1, cam0)


def test_euroc_rectification_geometry(euroc_micro: Path) -> None:
    """Body points seen by the raw distorted cameras land on one row after rectification and
    triangulate (eq. 10) back to themselves through ``R_B_C``/``p_B_C``."""
    ds = load_dataset(euroc_micro)
    assert ds.cam0 is not None and ds.cam1 is not None
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    rig = rect.rig
    assert not rect.identity
    assert rig.baseline == pytest.approx(0.1101, abs=2e-4)  # |p_C0 - p_C1| of the two T_BS
    np.testing.assert_allclose(rig.R_B_C @ rig.R_B_C.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rig.p_B_C, ds.cam0.T_B_C[:3, 3])
    rng = np.random.default_rng(3)
    # Points 1.5-6 m in front of the left camera, within the central field of view.
    p_C0 = np.c_[rng.uniform(-0.5, 0.5, 40), rng.uniform(-0.4, 0.4, 40), rng.uniform(1.5, 6, 40)]
    T_B_C0, T_B_C1 = ds.cam0.T_B_C, ds.cam1.T_B_C
    p_B = p_C0 @ T_B_C0[:3, :3].T + T_B_C0[:3, 3]
    uv_raw = []
    for T, cam in ((T_B_C0, ds.cam0), (T_B_C1, ds.cam1)):
        T_C_B = np.linalg.inv(T)
        rvec, _ = cv2.Rodrigues(T_C_B[:3, :3])
        uv, _ = cv2.projectPoints(p_B, rvec, T_C_B[:3, 3], cam.K, cam.distortion)
        uv_raw.append(uv.reshape(-1, 2))
    uvl = rect.rectify_points(uv_raw[0])
    uvr = rect.rectify_points(uv_raw[1], right=True)
    np.testing.assert_allclose(uvl[:, 1], uvr[:, 1], atol=2e-3)  # same row
    p_C = rig.triangulate(uvl, uvr)
    p_B_back = p_C @ rig.R_B_C.T + rig.p_B_C
    err = np.linalg.norm(p_B_back - p_B, axis=1)
    assert np.all(err < 1e-4 * p_C0[:, 2] ** 2), err.max()


def test_euroc_images_rectify_to_rows(euroc_micro: Path) -> None:
    """Real images: corners matched left-right after remap lie on the same row (sub-pixel)."""
    ds = load_dataset(euroc_micro)
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    left, right = rect.rectify_pair(ds.left.load(0), ds.right.load(0))
    assert left.shape == (480, 752) and left.dtype == np.uint8
    pts = cv2.goodFeaturesToTrack(left, 300, 0.01, 10).reshape(-1, 2).astype(float)
    klt = KltOptions()
    # A loose row tolerance so the check measures the rectification, not the matcher's gate.
    opts = StereoMatchOptions(epipolar_max_px=20.0, fb_check=True)
    uvr, ok = match_sparse(Pyramid(left, klt), Pyramid(right, klt), pts, opts, klt)
    assert ok.sum() > 100
    dv = np.abs(uvr[ok, 1] - pts[ok, 1])
    assert np.median(dv) < 0.15
    # No systematic row offset (a wrong R1/R2 would tilt or shift the rows).
    assert abs(float(np.median(uvr[ok, 1] - pts[ok, 1]))) < 0.05


def test_point_rectification_round_trip_and_maps(euroc_micro: Path) -> None:
    """``unrectify_points`` inverts ``rectify_points`` (converged, sub-micro-pixel even in the
    image corners, where 5 undistortion iterations leave ~0.4 px) and agrees with the remap."""
    ds = load_dataset(euroc_micro)
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    rng = np.random.default_rng(21)
    pix = np.c_[rng.integers(0, 752, 500), rng.integers(0, 480, 500)]
    pix = np.vstack([pix, [[0, 0], [751, 0], [0, 479], [751, 479]]])
    for right in (False, True):
        raw = rect.unrectify_points(pix.astype(float), right=right)
        xy = rect.xymap_right if right else rect.xymap_left
        assert xy is not None
        np.testing.assert_allclose(raw, xy[pix[:, 1], pix[:, 0]], atol=1e-3)
        np.testing.assert_allclose(rect.rectify_points(raw, right=right), pix, atol=1e-6)


def test_sample_rectified_matches_remapped_image(euroc_micro: Path) -> None:
    ds = load_dataset(euroc_micro)
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    raw_r = ds.right.load(0)
    img = rect.rectify_right(raw_r)
    rows = np.arange(100, 111)[None, :, None] + np.array([0, 200])[:, None, None]  # (2, 11, 1)
    cols = np.arange(300, 440)[None, None, :]
    got = rect.sample_rectified(raw_r, rows, np.broadcast_to(cols, (2, 1, 140)), right=True)
    want = img[rows, cols].astype(np.float32)
    assert got.shape == (2, 11, 140) and got.dtype == np.float32
    # Same bilinear sampling; the whole-image remap uses 1/32 px fixed-point weights.
    assert np.mean(np.abs(got - want)) < 0.5 and np.max(np.abs(got - want)) <= 4


def test_sparse_match_on_raw_images_agrees_with_rectified(euroc_micro: Path) -> None:
    """Matching on the raw images (rectifying only the points) finds the same right pixels as
    matching on remapped images."""
    ds = load_dataset(euroc_micro)
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    raw_l, raw_r = ds.left.load(0), ds.right.load(0)
    left, right = rect.rectify_pair(raw_l, raw_r)
    pts = cv2.goodFeaturesToTrack(left, 300, 0.01, 10).reshape(-1, 2).astype(float)
    klt, opts = KltOptions(), StereoMatchOptions()
    uvr_a, ok_a = match_sparse(Pyramid(left, klt), Pyramid(right, klt), pts, opts, klt)
    uvr_b, ok_b = match_sparse(Pyramid(raw_l, klt), Pyramid(raw_r, klt), pts, opts, klt,
                               rectifier=rect)  # fmt: skip
    both = ok_a & ok_b
    assert both.sum() > 100 and both.sum() > 0.9 * max(ok_a.sum(), ok_b.sum())
    d = uvr_a[both] - uvr_b[both]
    # Two KLT solutions on differently sampled windows: sub-0.1 px apart, no systematic offset.
    assert np.median(np.abs(d)) < 0.1
    assert np.all(np.abs(np.median(d, axis=0)) < 0.03)
