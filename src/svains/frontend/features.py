"""Corner detection spread over the image by grid bucketing, topped up where tracks were lost."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class DetectorOptions:
    """Corner detector settings.

    ``grid`` (cols, rows) of buckets; ``per_cell`` target features per bucket (existing tracks
    count against it); ``method`` "gftt" (Shi-Tomasi) or "fast"; ``min_distance_px`` between a new
    corner and any other feature; ``border_px`` keeps corners away from the image edge (KLT window).
    """

    grid: tuple[int, int] = (8, 6)
    per_cell: int = 10
    method: str = "fast"
    quality_level: float = 0.001
    fast_threshold: int = 10
    min_distance_px: float = 8.0
    border_px: int = 12


def _cells(uv: F64, shape: tuple[int, int], grid: tuple[int, int]) -> NDArray[np.int64]:
    """Flat bucket index (N,) of pixels ``uv`` (N, 2) in an image of ``shape`` (H, W)."""
    h, w = shape
    gx, gy = grid
    cx = np.clip((uv[:, 0] * gx / w).astype(np.int64), 0, gx - 1)
    cy = np.clip((uv[:, 1] * gy / h).astype(np.int64), 0, gy - 1)
    return cy * gx + cx


def _raw_corners(
    img: U8, opts: DetectorOptions, max_corners: int, mask: U8 | None = None
) -> tuple[F64, F64]:
    """Candidate corners (N, 2) px and their scores (N,), strongest first, where ``mask`` (H, W)
    is non-zero (everywhere if None)."""
    if opts.method == "fast":
        fast = cv2.FastFeatureDetector_create(threshold=opts.fast_threshold, nonmaxSuppression=True)
        kps = fast.detect(img, mask)
        if not kps:
            return np.zeros((0, 2)), np.zeros(0)
        uv = cv2.KeyPoint_convert(kps).astype(float).reshape(-1, 2)
        score = np.fromiter((k.response for k in kps), dtype=float, count=len(kps))
        order = np.argsort(-score, kind="stable")
        return uv[order], score[order]
    pts = cv2.goodFeaturesToTrack(
        img, maxCorners=max_corners, qualityLevel=opts.quality_level,
        minDistance=max(1.0, opts.min_distance_px * 0.7), blockSize=5, mask=mask,
    )
    if pts is None:
        return np.zeros((0, 2)), np.zeros(0)
    uv = pts.reshape(-1, 2).astype(float)
    # goodFeaturesToTrack returns corners by decreasing quality: rank is the score.
    return uv, -np.arange(uv.shape[0], dtype=float)


def _cell_mask(quota: NDArray[np.int64], shape: tuple[int, int], opts: DetectorOptions) -> U8:
    """uint8 mask (H, W): 255 inside buckets that still need corners, away from the border."""
    h, w = shape
    gx, gy = opts.grid
    need = (quota.reshape(gy, gx) > 0).astype(np.uint8) * 255
    # Nearest-neighbour upsampling (cv2, not fancy indexing: this runs on every frame).
    mask = cv2.resize(need, (w, h), interpolation=cv2.INTER_NEAREST)
    b = opts.border_px
    mask[:b] = 0
    mask[h - b :] = 0
    mask[:, :b] = 0
    mask[:, w - b :] = 0
    return mask


def _mark(occ: NDArray[np.bool_], uv: F64, s: float) -> None:
    """Set the cells of ``occ`` (cell size ``s`` px) that contain pixels ``uv`` (N, 2)."""
    ij = np.floor(uv / s).astype(np.int64)
    ok = (ij >= 0).all(axis=1) & (ij[:, 0] < occ.shape[1]) & (ij[:, 1] < occ.shape[0])
    occ[ij[ok, 1], ij[ok, 0]] = True


def detect_corners(
    img: U8, uv_existing: F64, opts: DetectorOptions, uv_blocked: F64 | None = None
) -> F64:
    """New corners (N, 2) px in ``img`` (H, W) uint8 spread over a grid, avoiding existing
    features ``uv_existing`` (M, 2) and filling each bucket up to ``opts.per_cell``.

    ``uv_blocked`` (K, 2) px: further places to avoid (e.g. corners that recently failed to
    match) without counting against a bucket's quota. Only buckets short of features are
    searched (a detector mask), which also keeps the candidate list short.
    """
    h, w = img.shape[:2]
    gx, gy = opts.grid
    n_cells = gx * gy
    uv_existing = np.asarray(uv_existing, dtype=float).reshape(-1, 2)
    have = np.bincount(_cells(uv_existing, (h, w), opts.grid), minlength=n_cells)
    quota = np.maximum(opts.per_cell - have, 0)
    if quota.sum() == 0:
        return np.zeros((0, 2))
    mask = _cell_mask(quota, (h, w), opts)
    uv, _ = _raw_corners(img, opts, max_corners=4 * opts.per_cell * n_cells, mask=mask)
    if uv.shape[0] == 0:
        return uv
    b = opts.border_px
    keep = (uv[:, 0] >= b) & (uv[:, 0] <= w - 1 - b) & (uv[:, 1] >= b) & (uv[:, 1] <= h - 1 - b)
    uv = uv[keep]
    if uv.shape[0] and (uv_existing.shape[0] or uv_blocked is not None):
        # Occupancy image at min-distance resolution: a coarse but loop-free proximity test.
        s = max(opts.min_distance_px, 1.0)
        occ = np.zeros((int(h / s) + 2, int(w / s) + 2), dtype=bool)
        _mark(occ, uv_existing, s)
        if uv_blocked is not None:
            # Blocked places also block their neighbouring cells: the same edge or occlusion
            # otherwise comes back as a corner a pixel away, across a cell border.
            blk = np.zeros_like(occ)
            _mark(blk, np.asarray(uv_blocked, dtype=float).reshape(-1, 2), s)
            occ |= cv2.dilate(blk.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        cand = np.floor(uv / s).astype(np.int64)
        uv = uv[~occ[cand[:, 1], cand[:, 0]]]
    if uv.shape[0] == 0:
        return uv
    cell = _cells(uv, (h, w), opts.grid)
    # Rank of each candidate within its bucket (candidates are already strongest first).
    order = np.argsort(cell, kind="stable")
    sorted_cells = cell[order]
    first = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size) - first
    return uv[rank < quota[cell]]
