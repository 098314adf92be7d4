"""Left-right matching in a rectified pair: sparse KLT along the epipolar row, or a dense
disparity map (OpenCV SGBM, or ELAS through the optional ``pyelas`` binding) sampled at corners.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from svains.errors import ConfigError
from svains.frontend.rectify import StereoRectifier
from svains.frontend.tracking import KltOptions, Pyramid, track_klt

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]

log = logging.getLogger(__name__)

try:  # Optional: pyelas (GPLv3) only builds with numpy's headers on the include path.
    import elas as _elas
except ImportError:  # pragma: no cover - depends on the machine
    _elas = None


def elas_available() -> bool:
    """True when the ``pyelas`` binding imports."""
    return _elas is not None


@dataclass(frozen=True)
class StereoMatchOptions:
    """Left-right matching: ``method`` "sparse" (KLT), "sgbm" or "elas" (dense);
    ``epipolar_max_px`` row tolerance; disparity range px; SGBM block size; ``klt_levels``
    pyramid levels and ``klt_win_px`` window of the left-right KLT refinement (its start is
    already close; a small window limits foreground fattening at depth edges. No pyramid level
    above the base: the seed, the predicted disparity or the row search, is within a pixel or
    two, and a coarse level only lets KLT drift to another match; with one level EuRoC V1_01
    micro kept fewer inliers (193 against 210) and OpenCV, which cannot take prebuilt pyramids
    in its Python binding (``tracking.Pyramid``), spent 0.5 ms more per pair building it);
    ``fb_check`` adds a right-to-left pass (the row, disparity-range and row-search agreement
    checks always apply)."""

    method: str = "sparse"
    epipolar_max_px: float = 1.0
    min_disparity_px: float = 0.3
    max_disparity_px: float = 128.0
    sgbm_block: int = 5
    klt_levels: int = 0
    klt_win_px: int = 13
    fb_check: bool = False


def _windows(img: U8, row: NDArray[np.int64], col: NDArray[np.int64], half: int,
             before: int) -> U8:  # fmt: skip
    """Windows (N, 2 half + 1, before + half + 1) of ``img`` (H, W): rows ``row ± half``,
    columns ``col - before`` to ``col + half``, edge-replicated outside the image. Windows
    inside are block copies from a strided view (no padded copy of the whole image, which
    cost more than the search); the few that cross an edge gather clipped indices."""
    h, w = img.shape
    k = 2 * half + 1
    out = np.empty((row.size, k, before + half + 1), np.uint8)
    inside = (row >= half) & (row < h - half) & (col >= before) & (col < w - half)
    view = sliding_window_view(img, (k, before + half + 1))
    out[inside] = view[row[inside] - half, col[inside] - before]
    if not inside.all():
        o = ~inside
        rows = np.clip(row[o, None] + np.arange(-half, half + 1), 0, h - 1)
        cols = np.clip(col[o, None] + np.arange(-before, half + 1), 0, w - 1)
        out[o] = img[rows[:, :, None], cols[:, None, :]]
    return out


def block_match_rows(
    img_left: U8, img_right: U8, uv_left: F64, max_disparity_px: float, half: int = 5,
    min_ncc: float = 0.8, uniqueness: float = 0.97, rectifier: StereoRectifier | None = None,
) -> tuple[F64, Bool]:
    """Integer disparity (N,) px of left corners (N, 2) by a 1-D zero-mean NCC search along the
    same row of the right image, vectorised over features; validity (N,) requires a correlation
    above ``min_ncc`` and no second peak (> 1 px away) within ``uniqueness`` of the best one.

    Gives the KLT refinement a start that is robust to repetitive texture and large disparities.
    ``uv_left`` is rectified; with a ``rectifier`` the images are the raw ones and only the
    patches and strips searched are resampled to rectified geometry.
    """
    uv = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    n = uv.shape[0]
    D = int(max_disparity_px)
    if n == 0:
        return np.zeros(0), np.zeros(0, dtype=bool)
    h, w = img_left.shape
    k = 2 * half + 1
    col = np.rint(uv[:, 0]).astype(np.int64)
    row = np.rint(uv[:, 1]).astype(np.int64)
    row, col = np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)
    if rectifier is None:
        lp = _windows(img_left, row, col, half, half).astype(np.float32)  # (N, k, k)
        rs = _windows(img_right, row, col, half, half + D).astype(np.float32)  # (N, k, D+k)
    else:
        off = np.arange(-half, half + 1)
        rows = np.clip(row[:, None] + off, 0, h - 1)[:, :, None]  # (N, k, 1)
        cols_l = np.clip(col[:, None] + off, 0, w - 1)[:, None, :]
        lp = rectifier.sample_rectified(img_left, rows, cols_l)
        sc = np.arange(-half - D, half + 1)  # right strip columns, disparity D .. 0
        cols_r = np.clip(col[:, None] + sc, 0, w - 1)[:, None, :]
        rs = rectifier.sample_rectified(img_right, rows, cols_r, right=True)
    a = lp - lp.mean(axis=(1, 2), keepdims=True)  # (N, k, k) zero mean
    # Correlation of the zero-mean left patch with every right window (sum over patch columns j);
    # a zero-mean template makes the right window's mean drop out of the numerator.
    num = np.zeros((n, D + 1), np.float32)
    for j in range(k):
        num += np.matmul(a[:, None, :, j], rs[:, :, j : j + D + 1])[:, 0]
    # Window energy by cumulative sums along the strip.
    c1 = np.concatenate([np.zeros((n, 1), np.float32), np.cumsum(rs.sum(axis=1), axis=1)], 1)
    c2 = np.concatenate([np.zeros((n, 1), np.float32), np.cumsum((rs * rs).sum(axis=1), axis=1)], 1)
    s1 = c1[:, k:] - c1[:, :-k]
    s2 = c2[:, k:] - c2[:, :-k]
    var_b = np.maximum(s2 - s1 * s1 / (k * k), 0.0)
    den = np.sqrt((a * a).sum(axis=(1, 2))[:, None] * var_b) + 1e-3
    ncc = (num / den)[:, ::-1]  # index = disparity
    best = np.argmax(ncc, axis=1)
    peak = ncc[np.arange(n), best]
    far = np.abs(np.arange(D + 1)[None, :] - best[:, None]) > 1
    second = np.where(far, ncc, -np.inf).max(axis=1)
    ok = (peak >= min_ncc) & (second < uniqueness * peak)
    # The search must not run off the left edge of the right image.
    ok &= col - best >= 0
    return best.astype(float), ok


def match_sparse(
    left: Pyramid, right: Pyramid, uv_left: F64, opts: StereoMatchOptions, klt: KltOptions,
    disparity_guess: F64 | None = None, rectifier: StereoRectifier | None = None,
) -> tuple[F64, Bool]:
    """Right pixels (N, 2) of left corners ``uv_left`` (N, 2) by KLT, and validity (N,):
    forward-backward consistent, on the same row within ``epipolar_max_px``, disparity in range.

    ``disparity_guess`` (N,) px seeds the search, e.g. the previous disparity of a tracked
    feature; where it is NaN (or for all corners when it is ``None``) a row search gives the start.
    Pixels in and out are rectified. Without ``rectifier`` (or with an identity one) the pyramids
    hold rectified images; otherwise they hold the raw images: KLT then runs between the raw
    positions of the rectified start and guess, and its result is rectified for the checks.
    """
    uv_left = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    n = uv_left.shape[0]
    if n == 0:
        return uv_left.copy(), np.zeros(0, dtype=bool)
    geo = None if rectifier is None or rectifier.identity else rectifier
    if disparity_guess is None:
        d0 = np.full(n, np.nan)
    else:
        d0 = np.asarray(disparity_guess, dtype=float).reshape(-1).copy()
    searched = ~np.isfinite(d0)
    ok0 = np.ones(n, dtype=bool)
    if searched.any():
        d_row, ok_row = block_match_rows(
            left.image, right.image, uv_left[searched], opts.max_disparity_px, rectifier=geo
        )
        d0[searched] = d_row
        ok0[searched] = ok_row
    guess = uv_left - np.stack([d0, np.zeros_like(d0)], axis=1)
    start = uv_left
    if geo is not None:
        start, guess = geo.unrectify_points(uv_left), geo.unrectify_points(guess, right=True)
    klt_lr = replace(klt, win_px=opts.klt_win_px)
    uv_right, ok = track_klt(
        left, right, start, klt_lr, guess=guess, max_level=opts.klt_levels,
        fb_check=opts.fb_check,
    )
    if geo is not None:
        uv_right = geo.rectify_points(uv_right, right=True)
    ok &= ok0 & np.isfinite(uv_right).all(axis=1)
    disp = uv_left[:, 0] - uv_right[:, 0]
    # KLT must refine a row-search start, not wander off to another repetition of the texture.
    ok &= ~searched | (np.abs(disp - d0) <= 2.0)
    ok &= np.abs(uv_right[:, 1] - uv_left[:, 1]) <= opts.epipolar_max_px
    ok &= (disp >= opts.min_disparity_px) & (disp <= opts.max_disparity_px)
    return uv_right, ok


def dense_disparity(img_left: U8, img_right: U8, opts: StereoMatchOptions) -> F64:
    """Dense disparity (H, W) px of the left image (NaN where invalid), SGBM or ELAS."""
    if opts.method == "elas":
        if _elas is None:
            raise ConfigError("dense method 'elas' needs the pyelas binding (not installed)")
        e = _elas.Elas()
        e.set_preset(_elas.PRESET_ROBOTICS)
        e.disp_max = int(opts.max_disparity_px)
        e.postprocess_only_left = True
        d_left, _ = e.process(np.ascontiguousarray(img_left), np.ascontiguousarray(img_right))
        d = np.asarray(d_left, dtype=float)
        d[d <= 0] = np.nan
        return d
    if opts.method != "sgbm":
        raise ConfigError(f"unknown dense disparity method {opts.method!r} (sgbm or elas)")
    n_disp = int(np.ceil(opts.max_disparity_px / 16.0) * 16)
    b = opts.sgbm_block
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=max(16, n_disp), blockSize=b,
        P1=8 * b * b, P2=32 * b * b, disp12MaxDiff=1, uniquenessRatio=10,
        speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    d = sgbm.compute(img_left, img_right).astype(float) / 16.0  # fixed point, 4 fractional bits
    d[d <= 0] = np.nan
    return d


def match_dense(disparity: F64, uv_left: F64, opts: StereoMatchOptions) -> tuple[F64, Bool]:
    """Right pixels (N, 2) of ``uv_left`` (N, 2) read from a dense ``disparity`` map (H, W) at the
    nearest pixel; validity (N,) where the disparity exists and is in range."""
    uv_left = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    h, w = disparity.shape
    col = np.clip(np.rint(uv_left[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(uv_left[:, 1]).astype(np.int64), 0, h - 1)
    d = disparity[row, col] if uv_left.shape[0] else np.zeros(0)
    ok = np.isfinite(d) & (d >= opts.min_disparity_px) & (d <= opts.max_disparity_px)
    d = np.where(ok, d, 0.0)
    uv_right = np.stack([uv_left[:, 0] - d, uv_left[:, 1]], axis=1)
    return uv_right, ok
