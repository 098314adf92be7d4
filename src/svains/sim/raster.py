"""Raster helpers of the renderer (:mod:`svains.sim.render`): texture pyramids and tiles, 2-D
polygon clipping, and the per-frame face set-up vectorised over all candidate faces.

With :mod:`svains.sim.render`, the only modules of ``svains.sim`` importing OpenCV
(documented exception: the simulator draws images).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from svains.sim.world import Face

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

FACE_PAD = 4  # texels of replicated border around face textures (bilinear edge support)
FACE_LEVELS = 4  # pyramid levels below a face texture at most
# a masked face pixel lies within 1 px of the projected polygon: these offsets span that hull
HULL_OFFSETS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def pyramid(tex: U8, levels: int, wrap: bool) -> list[U8]:
    """Texture pyramid (level 0 = ``tex``); ``wrap`` keeps a periodic tile periodic."""
    out = [tex]
    for _ in range(levels):
        prev = out[-1]
        if min(prev.shape) < 8:
            break
        if wrap:
            pad = np.pad(prev, 4, mode="wrap")
            out.append(cv2.pyrDown(pad)[2:-2, 2:-2].copy())
        else:
            out.append(cv2.pyrDown(prev))
    return out


def padded_face_pyramid(tex: U8) -> list[U8]:
    """Face texture pyramid, every level with a FACE_PAD-texel replicated border."""
    return [cv2.copyMakeBorder(t, FACE_PAD, FACE_PAD, FACE_PAD, FACE_PAD, cv2.BORDER_REPLICATE)
            for t in pyramid(tex, FACE_LEVELS, wrap=False)]


def pyramid_shapes(shape: tuple[int, int], levels: int) -> list[tuple[int, int]]:
    """(H, W) of every level :func:`pyramid` (``wrap=False``) builds from a ``shape`` texture."""
    out = [shape]
    for _ in range(levels):
        h, w = out[-1]
        if min(h, w) < 8:
            break
        out.append(((h + 1) // 2, (w + 1) // 2))
    return out


def tile(tex: U8, side: int) -> U8:
    """Periodic tile ``tex`` (P, P) repeated to (side, side) (``side`` >= P)."""
    reps = -(-side // tex.shape[0])
    return np.ascontiguousarray(np.tile(tex, (reps, reps))[:side, :side])


def level_scale(level: int) -> F64:
    """Level-``level`` texel coords -> level-0 texel coords: ``cv2.pyrDown``'s texel i is
    centred on texel 2i of the level above (a 5-tap kernel about it), so x0 = 2^level · x.
    (An offset of (2^level - 1)/2, right for 2x2 box averaging, drew the texture 0.5 / 1.5 /
    3.5 texels off at levels 1 / 2 / 3: ground corners 0.1-0.35 px off beyond 5 m, the scene
    not rigid as the level changed: a user's probe.)"""
    k = float(2**level)
    return np.array([[k, 0, 0], [0, k, 0], [0, 0, 1.0]])


def clip_polygon_2d(poly: F64, a: F64, c: float) -> F64:
    """Part of convex polygon (K, D) where ``a·x + c >= 0`` (Sutherland-Hodgman, one plane)."""
    if len(poly) == 0:
        return poly
    s = poly @ a + c
    out = []
    for k in range(len(poly)):
        j = (k + 1) % len(poly)
        if s[k] >= 0:
            out.append(poly[k])
        if (s[k] >= 0) != (s[j] >= 0):
            out.append(poly[k] + (poly[j] - poly[k]) * (s[k] / (s[k] - s[j])))
    return np.array(out).reshape(-1, poly.shape[1])


@dataclass(frozen=True)
class FaceTable:
    """Per-face constants of a world, stacked (F faces; triangles repeat vertex 0)."""

    verts_W: F64  # (F, 4, 3) m
    n_verts: NDArray[np.int_]  # (F,)
    normals_W: F64  # (F, 3) outward unit normals
    u_W: F64  # (F, 3) m per texel along s
    v_W: F64  # (F, 3) m per texel along t
    origin_W: F64  # (F, 3) m, texel (0, 0)
    n_levels: NDArray[np.int_]  # (F,) pyramid levels of each texture
    level_max_st: F64  # (F, FACE_LEVELS + 1, 2) largest (s, t) inside each padded level


def face_table(faces: Sequence[Face]) -> FaceTable:
    """Stack the constants of ``faces`` (textures' pyramid shapes included, not built)."""
    n = len(faces)
    verts = np.zeros((n, 4, 3))
    max_st = np.full((n, FACE_LEVELS + 1, 2), -1.0)
    n_levels = np.zeros(n, int)
    for k, f in enumerate(faces):
        verts[k, : len(f.vertices_W)] = f.vertices_W
        verts[k, len(f.vertices_W):] = f.vertices_W[0]  # repeat: harmless for bounds
        shapes = pyramid_shapes(f.texture.shape, FACE_LEVELS)
        n_levels[k] = len(shapes)
        max_st[k, : len(shapes)] = [(w + 2 * FACE_PAD - 1, h + 2 * FACE_PAD - 1)
                                    for h, w in shapes]
    return FaceTable(
        verts, np.array([len(f.vertices_W) for f in faces], dtype=int),
        np.array([f.normal_W for f in faces]).reshape(-1, 3),
        np.array([f.u_W for f in faces]).reshape(-1, 3),
        np.array([f.v_W for f in faces]).reshape(-1, 3),
        np.array([f.origin_W for f in faces]).reshape(-1, 3), n_levels, max_st,
    )


@dataclass(frozen=True)
class FaceSetup:
    """One frame's drawing parameters of F candidate faces (all vectorised, camera frame C)."""

    uv: F64  # (F, 8, 2) projected vertices of the near-clipped polygon (padded by repeats), px
    box: NDArray[np.int_]  # (F, 4) x0, y0, x1, y1 (clamped to the image)
    inv_depth: F64  # (F, 3) a, b, c with 1/z = a u + b v + c
    level: NDArray[np.int_]  # (F,) pyramid level
    M: F64  # (F, 3, 3) box pixel -> padded level texel (inverse map)
    constant_border: NDArray[np.bool_]  # (F,) the 1-px hull maps inside the padded texture


def _clip_near(v_C: F64, real: NDArray[np.bool_], z_near: float) -> tuple[F64, NDArray[np.int_]]:
    """Polygons ``v_C`` (F, 4, 3) (``real`` (F, 4) marks true vertices; a triangle repeats its
    first) clipped to ``z >= z_near``, vectorised Sutherland-Hodgman: (F, 8, 3) vertices, the
    kept ones first and the rest repeating the first, and the kept counts (F,)."""
    z = v_C[..., 2]
    inside = z >= z_near
    nxt = np.roll(v_C, -1, axis=1)
    cross = inside != np.roll(inside, -1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(cross, (z - z_near) / (z - nxt[..., 2]), 0.0)
    inter = v_C + (nxt - v_C) * frac[..., None]
    slots = np.stack([v_C, inter], axis=2).reshape(len(v_C), 8, 3)
    valid = np.stack([inside & real, cross], axis=2).reshape(len(v_C), 8)
    order = np.argsort(~valid, axis=1, kind="stable")
    slots = np.take_along_axis(slots, order[..., None], axis=1)
    n_kept = valid.sum(axis=1)
    pos = np.arange(8)[None, :] < n_kept[:, None]
    return np.where(pos[..., None], slots, slots[:, :1]), n_kept


def face_setup(
    table: FaceTable, idx: NDArray[np.int_], shift_W: F64, R_C_W: F64, t_C: F64, K: F64,
    K_inv: F64, size: tuple[int, int], z_near: float,
) -> FaceSetup:
    """Vectorised per-frame set-up of faces ``idx`` (F,), each partly beyond ``z_near`` m,
    displaced by ``shift_W`` (F, 3) m, seen by the camera ``R_C_W`` (3, 3), ``t_C`` (3,) m with
    intrinsics ``K`` (3, 3) (inverse ``K_inv``) and image ``size`` (W, H): near-clipped
    polygons, bounding boxes, inverse-depth planes, pyramid levels and warp matrices."""
    w, h = size
    f, cu, cv = K[0, 0], K[0, 2], K[1, 2]
    # (matmul and sums, not einsum: ~50 µs per small einsum call, measured)
    v4_C = (table.verts_W[idx] + shift_W[:, None]) @ R_C_W.T + t_C
    real = np.arange(4)[None, :] < table.n_verts[idx][:, None]
    v_C, n_kept = _clip_near(v4_C, real, z_near)
    uv = v_C[..., :2] / v_C[..., 2:] * f + [cu, cv]
    lo = np.floor(uv.min(axis=1)).astype(int)
    hi = np.ceil(uv.max(axis=1)).astype(int) + 1
    box = np.column_stack([np.maximum(lo, 0), np.minimum(hi, [w, h])])
    n_C = table.normals_W[idx] @ R_C_W.T
    d_C = (n_C * v4_C[:, 0]).sum(axis=1)
    inv_depth = (n_C @ K_inv) / d_C[:, None]
    # pyramid level from the footprint at the centroid (geometric mean over the slant)
    kept = np.arange(v_C.shape[1])[None, :] < n_kept[:, None]
    centre = (v_C * kept[..., None]).sum(axis=1) / n_kept[:, None]
    cos = np.abs((n_C * centre).sum(axis=1)) / np.linalg.norm(centre, axis=1)
    foot = centre[:, 2] / (f * np.sqrt(np.maximum(cos, 1e-3)))
    texel = np.linalg.norm(table.u_W[idx], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lv = np.floor(np.log2(np.maximum(foot / texel, 1.0)))
    level = np.clip(np.nan_to_num(lv, nan=0.0), 0, table.n_levels[idx] - 1).astype(int)
    # H0 maps level-0 texels (s, t, 1) to pixels; M = inverse of box-shift ∘ H0 ∘ level scale
    cols = np.stack([table.u_W[idx] @ R_C_W.T, table.v_W[idx] @ R_C_W.T,
                     (table.origin_W[idx] + shift_W) @ R_C_W.T + t_C], axis=-1)
    A = K @ cols
    A[:, 0] -= box[:, 0, None] * A[:, 2]
    A[:, 1] -= box[:, 1, None] * A[:, 2]
    k = 2.0 ** level  # pyrDown's texel i sits on texel 2i above (``level_scale``)
    scale = np.zeros((len(idx), 3, 3))
    scale[:, 0, 0] = scale[:, 1, 1] = k
    scale[:, 2, 2] = 1.0
    A = A @ scale
    M = np.linalg.inv(A)
    M[:, 0] += FACE_PAD * M[:, 2]
    M[:, 1] += FACE_PAD * M[:, 2]
    hull = (uv - box[:, None, :2])[:, :, None] + HULL_OFFSETS  # (F, 8, 4, 2)
    hull = hull.reshape(len(idx), -1, 2)
    st = hull @ M[:, :, :2].transpose(0, 2, 1) + M[:, None, :, 2]
    front = (st[..., 2] > 1e-9).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        st2 = st[..., :2] / st[..., 2:]
    max_st = table.level_max_st[idx, level]
    inside = (st2.min(axis=1) >= 0.0).all(axis=1) & (st2.max(axis=1) <= max_st).all(axis=1)
    return FaceSetup(uv, box, inv_depth, level, M, front & inside)
