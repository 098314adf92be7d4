"""Procedural grey textures rich in corners, with the exact texture coordinates of their corners.

Texture coordinates ``st`` = (column s, row t) with texel centres at integers, so the boundary
between texels ``i - 1`` and ``i`` is at ``i - 0.5``. Every generator returns the texture
(H, W) uint8 and the corners (K, 2) float64 that make good landmarks (L-corners of high-contrast
rectangles: window frames, paving stones, checker squares, pole bands); the ground tile's texture
comes as a function that composes it on demand. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


def periodic_noise(shape: tuple[int, int], rng: np.random.Generator, cells: int) -> F64:
    """Smooth periodic value noise (H, W) in [-1, 1]: a ``cells``-periodic random grid bilinearly
    upsampled with wrap-around, so tiles repeat seamlessly."""
    return _upsample_periodic(rng.uniform(-1.0, 1.0, (cells, cells)), shape)


def _upsample_periodic(grid: F64, shape: tuple[int, int]) -> F64:
    """The periodic grid (cells, cells) bilinearly upsampled to (H, W) with wrap-around."""
    h, w = shape
    cells = grid.shape[0]
    # separable bilinear interpolation: along x on the small grid, then along y
    xs = np.arange(w) * cells / w
    x0 = np.floor(xs).astype(int)
    fx = xs - x0
    gx = grid[:, x0] * (1 - fx) + grid[:, (x0 + 1) % cells] * fx  # (cells, W)
    ys = np.arange(h) * cells / h
    y0 = np.floor(ys).astype(int)
    fy = (ys - y0)[:, None]
    # In place (same operations, same order): the full-size temporaries dominate the cost.
    out = gx[y0]
    out *= 1 - fy
    upper = gx[(y0 + 1) % cells]
    upper *= fy
    out += upper
    return out


def _fbm(shape: tuple[int, int], grids: list[F64]) -> F64:
    """Fractal sum (H, W), roughly in [-1, 1], of the periodic noises of ``grids`` (octaves,
    coarse to fine, from :func:`_fbm_grids`)."""
    out = np.zeros(shape)
    amp, total = 1.0, 0.0
    for grid in grids:
        octave = _upsample_periodic(grid, shape)
        octave *= amp
        out += octave
        total += amp
        amp *= 0.65  # slow decay keeps fine grain for the near ground
    return out / total


def _fbm_grids(rng: np.random.Generator, base: int, octaves: int) -> list[F64]:
    """The random grids of :func:`_fbm`'s octaves (``base * 2**k`` cells)."""
    return [rng.uniform(-1.0, 1.0, (base * 2**k, base * 2**k)) for k in range(octaves)]


def _rect_corners(s0: F64, t0: F64, s1: F64, t1: F64) -> F64:
    """Boundary corners (4K, 2) of texel rectangles [s0, s1) x [t0, t1) (integer bounds)."""
    a, b = s0 - 0.5, s1 - 0.5
    c, d = t0 - 0.5, t1 - 0.5
    return np.stack(
        [np.stack([a, c], -1), np.stack([b, c], -1), np.stack([a, d], -1), np.stack([b, d], -1)],
        axis=1,
    ).reshape(-1, 2)


def ground_tile(
    size_px: int, rng: np.random.Generator, cell_px: int
) -> tuple[Callable[[], U8], F64]:
    """Square periodic ground tile: grassy fractal noise plus paving stones (one per cell of
    ``cell_px`` with probability 0.45). Returns the stones' corners (K, 2) and a function that
    composes the texture (``size_px``², uint8). Every random draw happens here, so the tile does
    not depend on whether (or when) it is composed; its pixels, the costly part, only images
    need."""
    n = size_px // cell_px
    grids = _fbm_grids(rng, 8, 7)
    grain = rng.standard_normal((size_px, size_px))
    occupied = rng.random((n, n)) < 0.45
    ci, cj = np.nonzero(occupied)
    margin = cell_px // 8
    w = rng.integers(cell_px // 4, cell_px - 2 * margin, len(ci))
    h = rng.integers(cell_px // 4, cell_px - 2 * margin, len(ci))
    s0 = cj * cell_px + margin + rng.integers(0, cell_px - 2 * margin - w + 1)
    t0 = ci * cell_px + margin + rng.integers(0, cell_px - 2 * margin - h + 1)
    tones = rng.choice([35.0, 60.0, 190.0, 220.0], len(ci))
    stones = [tones[k] + rng.normal(0, 4.0) for k in range(len(ci))]
    corners = _rect_corners(s0.astype(float), t0.astype(float), (s0 + w).astype(float),
                            (t0 + h).astype(float))

    def compose() -> U8:
        img = 110.0 + 45.0 * _fbm((size_px, size_px), grids)
        img += 3.0 * grain
        for k in range(len(ci)):
            img[t0[k] : t0[k] + h[k], s0[k] : s0[k] + w[k]] = stones[k]
        return np.clip(img, 0, 255).astype(np.uint8)

    return compose, corners


def wall_texture(
    width_px: int, height_px: int, rng: np.random.Generator, texel_m: float, windows: bool
) -> tuple[U8, F64]:
    """Brick wall (rows from the bottom, t grows downwards) with framed windows and a door."""
    t = np.arange(height_px)[:, None]
    s = np.arange(width_px)[None, :]
    brick_h = max(3, round(0.075 / texel_m))
    brick_w = max(6, round(0.24 / texel_m))
    row = t // brick_h
    shift = (row % 2) * (brick_w // 2)
    col = (s + shift) // brick_w
    base = rng.uniform(100, 150)
    tone = rng.normal(0, 12, (height_px // brick_h + 2, width_px // brick_w + 3))
    img = base + tone[row, col] + 8 * periodic_noise((height_px, width_px), rng, 6)
    mortar = ((t % brick_h) == 0) | (((s + shift) % brick_w) == 0)
    img = np.where(mortar, base + 45.0, img)
    corners: list[F64] = []
    if windows:
        win_w, win_h = round(0.9 / texel_m), round(1.1 / texel_m)
        frame = max(2, round(0.1 / texel_m))
        floors = max(1, int((height_px * texel_m - 0.6) // 2.6))
        n_cols = max(1, int(width_px * texel_m // 2.5))
        for fl in range(floors):
            tt0 = height_px - round((1.0 + 2.6 * fl) / texel_m) - win_h
            for c in range(n_cols):
                if rng.random() < 0.25 or tt0 < frame:
                    continue
                ss0 = round((c + 0.5) * width_px / n_cols) - win_w // 2
                img[tt0 - frame : tt0 + win_h + frame, ss0 - frame : ss0 + win_w + frame] = 225.0
                glass = 30.0 + rng.uniform(0, 25)
                img[tt0 : tt0 + win_h, ss0 : ss0 + win_w] = glass
                # inner (glass) corners: white frame on two sides, clean L-corners
                corners.append(_rect_corners(np.array([ss0]), np.array([tt0]),
                                             np.array([ss0 + win_w]), np.array([tt0 + win_h])))
    return np.clip(img, 0, 255).astype(np.uint8), (
        np.concatenate(corners) if corners else np.zeros((0, 2))
    )


def roof_texture(width_px: int, height_px: int, rng: np.random.Generator, texel_m: float) -> U8:
    """Roof tiles: staggered dark rows (no landmarks: roofs are seen at grazing angles)."""
    t = np.arange(height_px)[:, None]
    s = np.arange(width_px)[None, :]
    tile_h = max(3, round(0.2 / texel_m))
    tile_w = max(3, round(0.3 / texel_m))
    row = t // tile_h
    col = (s + (row % 2) * (tile_w // 2)) // tile_w
    tone = rng.normal(0, 15, (height_px // tile_h + 2, width_px // tile_w + 3))
    img = 70.0 + tone[row, col] - 30.0 * ((t % tile_h) < max(1, tile_h // 5))
    return np.clip(img, 0, 255).astype(np.uint8)


def checker_texture(
    width_px: int, height_px: int, rng: np.random.Generator, square_px: int
) -> tuple[U8, F64]:
    """Crate side: checker of ``square_px`` squares with random greys; X-corners returned."""
    t = np.arange(height_px)[:, None] // square_px
    s = np.arange(width_px)[None, :] // square_px
    parity = (t + s) % 2
    dark = rng.uniform(20, 70)
    light = rng.uniform(170, 235)
    img = np.where(parity == 0, dark, light) + rng.normal(0, 3.0, (height_px, width_px))
    # interior X-corners with at least half a square on every side (thin border strips give
    # L-corners against the face edge, which detectors place poorly)
    ks = np.arange(1, width_px // square_px + 1)
    kt = np.arange(1, height_px // square_px + 1)
    ks = ks[ks * square_px <= width_px - square_px // 2]
    kt = kt[kt * square_px <= height_px - square_px // 2]
    ss, tt = np.meshgrid(ks * square_px - 0.5, kt * square_px - 0.5)
    corners = np.column_stack([ss.ravel(), tt.ravel()])
    return np.clip(img, 0, 255).astype(np.uint8), corners


def band_texture(width_px: int, height_px: int, band_px: int) -> tuple[U8, F64]:
    """Pole: horizontal black/white bands (t direction); band corners on the face edges are
    not returned (silhouette corners are not fixed 3-D points)."""
    t = np.arange(height_px)[:, None] // band_px
    img = np.where(t % 2 == 0, 30, 215) * np.ones((1, width_px))
    return img.astype(np.uint8), np.zeros((0, 2))


def object_texture(width_px: int, height_px: int, rng: np.random.Generator) -> tuple[U8, F64]:
    """Moving object's side (vehicle/person-like clutter): randomly sized and placed dark or
    light panels and thin strokes on a mottled mid-grey, never periodic; their L-corners returned.

    Dart throwing with a 3-texel gap keeps every returned corner a clean L-corner (no other
    panel inside a 3-texel ring) and random sizes/positions make every neighbourhood different,
    so a tracker cannot slip onto a look-alike neighbour as it can on a checker.
    """
    img = 120.0 + 18.0 * periodic_noise((height_px, width_px), rng, 5)
    img += rng.normal(0, 3.0, (height_px, width_px))
    gap = 3
    busy = np.zeros((height_px + 2 * gap, width_px + 2 * gap), bool)  # padded occupancy
    rects: list[tuple[int, int, int, int]] = []
    attempts = max(20, int(6 * width_px * height_px / 18.0**2))
    for _ in range(attempts):
        if rng.random() < 0.3:  # text-like stroke: thin bar, either orientation
            w, h = int(rng.integers(3, 6)), int(rng.integers(10, 24))
            if rng.random() < 0.5:
                w, h = h, w
        else:  # panel / label
            w, h = int(rng.integers(6, 26)), int(rng.integers(6, 26))
        if w > width_px - 2 * gap or h > height_px - 2 * gap:
            continue
        s0 = int(rng.integers(gap, width_px - gap - w + 1))
        t0 = int(rng.integers(gap, height_px - gap - h + 1))
        # padded coordinates: the rectangle's gap-dilated box is [t0, t0 + h + 2 gap)
        if busy[t0 : t0 + h + 2 * gap, s0 : s0 + w + 2 * gap].any():
            continue
        busy[t0 + gap : t0 + h + gap, s0 + gap : s0 + w + gap] = True
        tone = rng.uniform(15, 60) if rng.random() < 0.5 else rng.uniform(185, 240)
        img[t0 : t0 + h, s0 : s0 + w] = tone + rng.normal(0, 3.0, (h, w))
        rects.append((s0, t0, s0 + w, t0 + h))
    if not rects:
        return np.clip(img, 0, 255).astype(np.uint8), np.zeros((0, 2))
    r = np.array(rects, dtype=float)
    corners = _rect_corners(r[:, 0], r[:, 1], r[:, 2], r[:, 3])
    return np.clip(img, 0, 255).astype(np.uint8), corners
