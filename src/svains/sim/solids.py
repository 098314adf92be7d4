"""Convex textured solids of the simulated world and the queries on them.

World frame W: z up, ground plane at ``ground_height``. Every solid is a convex polyhedron kept
twice: as outward textured faces (for rendering) and as half-spaces ``n·x <= d`` (for the
vectorised ray casting and landmark occlusion tests). A face maps texture coordinates ``(s, t)``
(texel centres at integers) to ``origin_W + s u_W + t v_W``. Here: :class:`Face`,
:class:`Solid`, :class:`World` (ray casting, moving solid, landmark positions) and the box/face
builders; :mod:`svains.sim.world` lays out the village with them. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

MOVING_SHARPNESS = 0.99  # 1 = triangle wave (instant turn), 0 = sine; 0.99 turns in ~2% of a period
MOVING_DIRECTION_W = np.array([1.0, 0.0, 0.0])
TextureMaker = Callable[[int, int], tuple[U8, F64]]


@dataclass
class Face:
    """Planar convex polygon ``vertices_W`` (K, 3), counter-clockwise seen from outside.

    Texel ``(s, t)`` is at ``origin_W + s u_W + t v_W``; ``u_W``, ``v_W`` (3,) m per texel.
    """

    vertices_W: F64
    origin_W: F64
    u_W: F64
    v_W: F64
    texture: U8
    solid: int

    @property
    def normal_W(self) -> F64:
        n = np.cross(self.u_W, self.v_W)
        # u right, v down seen from outside: u × v points into the solid
        return -n / np.linalg.norm(n)


@dataclass
class Solid:
    """Convex polyhedron: ``normals_W`` (P, 3), ``offsets`` (P,) with inside = ``n·x <= d``."""

    normals_W: F64
    offsets: F64
    moving: bool = False


@dataclass
class World:
    """Ground (periodic tile), solids, faces and landmarks (ids = row index).

    ``ground_pixels()`` composes the ground tile; :attr:`ground_texture` calls it once, on first
    use: a data set without images never pays for the 2048² tile."""

    ground_height: float
    ground_pixels: Callable[[], U8]
    ground_texel_m: float
    ground_origin_W: F64
    solids: list[Solid]
    faces: list[Face]
    landmarks_W: F64
    landmark_moving: NDArray[np.bool_]
    moving_direction_W: F64 = field(default_factory=lambda: np.zeros(3))
    moving_amplitude: float = 0.0
    moving_period_s: float = 1.0
    _spheres: tuple[F64, F64] | None = field(default=None, repr=False)

    @cached_property
    def ground_texture(self) -> U8:
        """The periodic ground tile (H, W) uint8."""
        return self.ground_pixels()

    def moving_offset_W(self, t_s: float) -> F64:
        """Displacement (3,) m of the moving solid at time ``t_s``: a walk back and forth.

        ``A asin(k sin(w t)) / asin(k) * direction`` with ``k`` = :data:`MOVING_SHARPNESS`: a
        triangle wave with rounded turns (smooth, 0 at t = 0, ``A`` at a quarter period), i.e.
        a nearly constant speed ``≈ 4 A / period`` (walking pace for the defaults) that stops
        only briefly to turn, unlike a sine, which dawdles near both ends."""
        w = 2 * np.pi / self.moving_period_s
        k = MOVING_SHARPNESS
        shape = np.arcsin(k * np.sin(w * t_s)) / np.arcsin(k)
        return self.moving_amplitude * shape * self.moving_direction_W

    def first_hit(self, t_s: float, o_W: F64, d_W: F64) -> tuple[F64, NDArray[np.intp]]:
        """First surface hit by rays ``o_W + t d_W`` (origin (3,), directions (N, 3)) with the
        solids placed at time ``t_s``: ray parameter (N,) (inf: sky) and solid index (N,)
        (-1: ground or sky). With unit-z camera rays, the parameter is the depth."""
        n, d = self.planes_at(t_s)  # (M, P, 3), (M, P)
        den = np.einsum("mpk,nk->nmp", n, d_W)
        num = d[None] - np.einsum("mpk,k->mp", n, o_W)[None]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = num / den
        enter = np.where(den < 0, tt, -np.inf).max(axis=2)
        leave = np.where(den > 0, tt, np.inf).min(axis=2)
        parallel_out = np.any((den == 0) & (num < 0), axis=2)
        hit = (enter <= leave) & (leave > 0) & ~parallel_out
        t_solid = np.where(hit, np.maximum(enter, 0.0), np.inf)
        best = np.argmin(t_solid, axis=1)
        t_best = t_solid[np.arange(len(best)), best]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_ground = np.where(d_W[:, 2] < 0, (self.ground_height - o_W[2]) / d_W[:, 2], np.inf)
        solid = np.where(t_best < t_ground, best, -1)
        return np.minimum(t_best, t_ground), solid

    def landmarks_at(self, t_s: float) -> F64:
        """Landmark positions (N, 3) at time ``t_s`` (moving ones displaced)."""
        if not self.landmark_moving.any():
            return self.landmarks_W
        out = self.landmarks_W.copy()
        out[self.landmark_moving] += self.moving_offset_W(t_s)
        return out

    def bounding_spheres_at(self, t_s: float) -> tuple[F64, F64]:
        """Centres (M, 3) m and radii (M,) m of spheres enclosing each solid at ``t_s``."""
        if self._spheres is None:
            verts: list[list[F64]] = [[] for _ in self.solids]
            for f in self.faces:
                verts[f.solid].append(f.vertices_W)
            centres, radii = [], []
            for v in verts:
                pts = np.concatenate(v)
                c = 0.5 * (pts.min(0) + pts.max(0))
                centres.append(c)
                radii.append(np.linalg.norm(pts - c, axis=1).max())
            self._spheres = (np.array(centres).reshape(-1, 3), np.array(radii))
        centres, radii = self._spheres
        moving = np.array([s.moving for s in self.solids], dtype=bool)
        if moving.any():
            centres = centres.copy()
            centres[moving] += self.moving_offset_W(t_s)
        return centres, radii

    def planes_at(self, t_s: float) -> tuple[F64, F64]:
        """Half-spaces of every solid padded to P planes: normals (M, P, 3), offsets (M, P)."""
        p = max(len(s.offsets) for s in self.solids)
        n = np.zeros((len(self.solids), p, 3))
        d = np.ones((len(self.solids), p))  # padding 0·x <= 1 always holds
        off = self.moving_offset_W(t_s)
        for k, s in enumerate(self.solids):
            n[k, : len(s.offsets)] = s.normals_W
            d[k, : len(s.offsets)] = s.offsets + (s.normals_W @ off if s.moving else 0.0)
        return n, d


def make_face(quad_W: F64, texel: float, solid: int, make_tex: TextureMaker) -> tuple[Face, F64]:
    """Face on polygon ``quad_W`` whose first three vertices are the texture's top-left,
    top-right and bottom-right corners; ``make_tex(w_px, h_px)`` -> (texture, corners_st)."""
    tl, tr, br = quad_W[0], quad_W[1], quad_W[2]
    width_m = np.linalg.norm(tr - tl)
    height_m = np.linalg.norm(br - tr)
    w_px = max(2, round(width_m / texel))
    h_px = max(2, round(height_m / texel))
    u = (tr - tl) / w_px
    v = (br - tr) / h_px
    tex, corners = make_tex(w_px, h_px)
    origin = tl + 0.5 * u + 0.5 * v
    face = Face(np.asarray(quad_W, float), origin, u, v, tex, solid)
    pts = origin + corners[:, :1] * u + corners[:, 1:2] * v if len(corners) else np.zeros((0, 3))
    return face, pts


def planes_from_faces(faces: list[Face], extra: list[tuple[F64, float]]) -> Solid:
    normals = [f.normal_W for f in faces] + [n for n, _ in extra]
    offsets = [float(f.normal_W @ f.vertices_W[0]) for f in faces] + [d for _, d in extra]
    return Solid(np.array(normals), np.array(offsets))


def box_corners(
    centre_xy: ArrayLike, size: tuple[float, float, float], yaw: float, z0: float
) -> F64:
    """Box corners (8, 3): bottom 0-3 then top 4-7, counter-clockwise seen from above."""
    c, s = np.cos(yaw), np.sin(yaw)
    hx, hy = 0.5 * size[0], 0.5 * size[1]
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    xy = local @ np.array([[c, s], [-s, c]]) + np.asarray(centre_xy, float)
    bottom = np.column_stack([xy, np.full(4, z0)])
    top = np.column_stack([xy, np.full(4, z0 + size[2])])
    return np.vstack([bottom, top])


def add_box(
    world_faces: list[Face],
    corners: F64,
    solid: int,
    side_tex: TextureMaker,
    top_tex: TextureMaker | None,
    texel: float,
) -> tuple[list[Face], F64]:
    """Four walls (+ top if ``top_tex``) of a box from :func:`box_corners`; returns the faces
    and the landmarks."""
    faces, pts = [], []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        at, bt = corners[4 + k], corners[4 + (k + 1) % 4]
        f, p = make_face(np.array([at, bt, b, a]), texel, solid, side_tex)
        faces.append(f)
        pts.append(p)
    if top_tex is not None:
        f, p = make_face(corners[[7, 6, 5, 4]], texel, solid, top_tex)
        faces.append(f)
        pts.append(p)
    world_faces.extend(faces)
    return faces, np.concatenate(pts)
