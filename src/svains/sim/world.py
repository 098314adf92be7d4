"""The village: textured ground plane and convex textured solids (houses, roofs, crates, poles).

World frame W: z up, ground plane at ``ground_height``. Every solid is a convex polyhedron kept
twice: as outward textured faces (for rendering) and as half-spaces ``n·x <= d`` (for the
vectorised ray occlusion test of landmarks). A face maps texture coordinates ``(s, t)`` (texel
centres at integers) to ``origin_W + s u_W + t v_W``. Landmarks are texture corners lifted to
3-D. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.sim.config import WorldConfig
from svains.sim.textures import (
    band_texture,
    checker_texture,
    ground_texture,
    object_texture,
    roof_texture,
    wall_texture,
)

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

WALL_TEXEL_M = 0.02
GROUND_TEXEL_M = 0.01
GROUND_TILE_PX = 2048
GROUND_CELL_PX = 110
_UP = np.array([0.0, 0.0, 1.0])
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
    """Ground (periodic tile), solids, faces and landmarks (ids = row index)."""

    ground_height: float
    ground_texture: U8
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


def _face(quad_W: F64, texel: float, solid: int, make_tex: TextureMaker) -> tuple[Face, F64]:
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


def _planes_from_faces(faces: list[Face], extra: list[tuple[F64, float]]) -> Solid:
    normals = [f.normal_W for f in faces] + [n for n, _ in extra]
    offsets = [float(f.normal_W @ f.vertices_W[0]) for f in faces] + [d for _, d in extra]
    return Solid(np.array(normals), np.array(offsets))


def _box(
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


def _add_box(
    world_faces: list[Face],
    corners: F64,
    solid: int,
    side_tex: TextureMaker,
    top_tex: TextureMaker | None,
    texel: float,
) -> tuple[list[Face], F64]:
    """Four walls (+ top if ``top_tex``) of a box from :func:`_box`; returns faces, landmarks."""
    faces, pts = [], []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        at, bt = corners[4 + k], corners[4 + (k + 1) % 4]
        f, p = _face(np.array([at, bt, b, a]), texel, solid, side_tex)
        faces.append(f)
        pts.append(p)
    if top_tex is not None:
        f, p = _face(corners[[7, 6, 5, 4]], texel, solid, top_tex)
        faces.append(f)
        pts.append(p)
    world_faces.extend(faces)
    return faces, np.concatenate(pts)


def _path_distance(xy: F64, path_xy: F64) -> F64:
    """Distance (N,) from points (N, 2) to the nearest path sample (M, 2)."""
    d = np.linalg.norm(xy[:, None, :] - path_xy[None, ::4, :], axis=2)
    return d.min(axis=1)


def build_world(cfg: WorldConfig, path_xy: F64, seed: int, ground_height: float = 0.0) -> World:
    """Village around the flight path ``path_xy`` (M, 2): houses in a ring outside it, houses,
    crates and poles inside it, none closer than ``cfg.clearance`` m to the path. With
    ``cfg.moving_object``, a vehicle-sized box with a non-periodic texture walks back and forth
    along :data:`MOVING_DIRECTION_W` straight ahead of a flight leg (see :func:`_crossing_spot`),
    drawn from its own RNG stream so the rest of the village is unchanged."""
    rng = np.random.default_rng(seed)
    lo, hi = path_xy.min(0), path_xy.max(0)
    faces: list[Face] = []
    solids: list[Solid] = []
    marks: list[F64] = []
    moving_mask: list[F64] = []
    placed: list[tuple[F64, float]] = []

    def free(c: F64, radius: float) -> bool:
        if _path_distance(c[None], path_xy)[0] < cfg.clearance + radius:
            return False
        return all(np.linalg.norm(c - pc) > radius + pr + 0.5 for pc, pr in placed)

    def sample(inner: bool, radius: float) -> F64 | None:
        for _ in range(200):
            if inner:
                c = rng.uniform(lo, hi)
            else:
                c = rng.uniform(lo - cfg.clearance - 12.0, hi + cfg.clearance + 12.0)
                if np.all((c > lo) & (c < hi)):
                    continue
            if free(c, radius):
                placed.append((c, radius))
                return c
        return None

    def house(c: F64, yaw: float) -> None:
        w, d = rng.uniform(4.0, 9.0), rng.uniform(4.0, 7.0)
        h, rh = rng.uniform(3.0, 6.0), rng.uniform(1.2, 2.2)
        corners = _box(c, (w, d, h), yaw, ground_height)
        sid = len(solids)

        def wall(wp: int, hp: int):
            return wall_texture(wp, hp, rng, WALL_TEXEL_M, windows=True)

        fs, pts = _add_box(faces, corners, sid, wall, None, WALL_TEXEL_M)
        top = corners[4:]
        solids.append(_planes_from_faces(fs, [(np.array([0, 0, 1.0]), ground_height + h),
                                              (np.array([0, 0, -1.0]), -ground_height)]))
        marks.append(pts)
        moving_mask.append(np.zeros(len(pts)))
        # gable roof along the box's local x axis: ridge over the middle of sides 1-2 and 3-0
        r0 = 0.5 * (top[3] + top[0]) + rh * _UP
        r1 = 0.5 * (top[1] + top[2]) + rh * _UP
        rid = len(solids)

        def roof(wp: int, hp: int):
            return roof_texture(wp, hp, rng, WALL_TEXEL_M), np.zeros((0, 2))

        def gable(wp: int, hp: int):
            return wall_texture(wp, hp, rng, WALL_TEXEL_M, windows=False)[0], np.zeros((0, 2))

        roof_faces = [
            _face(np.array([r0, r1, top[1], top[0]]), WALL_TEXEL_M, rid, roof)[0],
            _face(np.array([r1, r0, top[3], top[2]]), WALL_TEXEL_M, rid, roof)[0],
        ]
        # gable triangles: texture spans the triangle's bounding rectangle
        for a, b, r in ((top[1], top[2], r1), (top[3], top[0], r0)):
            f, _ = _face(np.array([a + rh * _UP, b + rh * _UP, b, a]), WALL_TEXEL_M, rid,
                         gable)
            f.vertices_W = np.array([r, b, a])
            roof_faces.append(f)
        faces.extend(roof_faces)
        solids.append(_planes_from_faces(roof_faces, [(np.array([0, 0, -1.0]), -(ground_height
                                                                                   + h))]))

    def crate(c: F64, yaw: float, size: tuple[float, float, float] | None = None,
              tex: TextureMaker | None = None, moving: bool = False) -> None:
        if size is None:
            size = (rng.uniform(0.8, 2.0), rng.uniform(0.8, 2.0), rng.uniform(0.8, 2.0))
        corners = _box(c, size, yaw, ground_height)
        if tex is None:
            tex = partial(checker_texture, rng=rng, square_px=int(rng.integers(10, 16)))
        fs, pts = _add_box(faces, corners, len(solids), tex, tex, WALL_TEXEL_M)
        s = _planes_from_faces(fs, [(np.array([0, 0, -1.0]), -ground_height)])
        s.moving = moving
        solids.append(s)
        marks.append(pts)
        moving_mask.append(np.full(len(pts), 1.0 if moving else 0.0))

    def pole(c: F64) -> None:
        corners = _box(c, (0.25, 0.25, rng.uniform(3.0, 5.0)), rng.uniform(0, np.pi), 0.0)
        corners[:, 2] += ground_height

        def bands(wp: int, hp: int):
            return band_texture(wp, hp, 25)

        fs, _ = _add_box(faces, corners, len(solids), bands, bands, WALL_TEXEL_M)
        solids.append(_planes_from_faces(fs, [(np.array([0, 0, -1.0]), -ground_height)]))

    # houses face the path: yaw a multiple of 90 deg plus a little
    for _ in range(cfg.n_outer_houses):
        c = sample(False, 5.5)
        if c is not None:
            house(c, rng.integers(0, 4) * 0.5 * np.pi + rng.uniform(-0.15, 0.15))
    for k in range(cfg.n_inner_objects):
        big = k % 2 == 0
        c = sample(True, 5.5 if big else 1.5)
        if c is not None:
            if big:
                house(c, rng.uniform(-0.3, 0.3))
            else:
                crate(c, rng.uniform(0, np.pi))
    for _ in range(cfg.n_poles):
        c = sample(rng.random() < 0.5, 0.3)
        if c is not None:
            pole(c)
    direction = np.zeros(3)
    if cfg.moving_object:
        # own stream: the moving object does not change the rest of the village
        mrng = np.random.default_rng([seed, 2])
        # vehicle-sized box, long side along its motion (length, width, height) m
        size = (mrng.uniform(2.0, 2.6), mrng.uniform(1.0, 1.4), mrng.uniform(1.4, 1.8))
        half = 0.5 * float(np.hypot(size[0], size[1]))
        swing = cfg.moving_amplitude * MOVING_DIRECTION_W[:2]

        def fits(c: F64) -> bool:
            # the object sweeps a capsule: segment c ± swing, radius ``half``
            a = np.linspace(-1.0, 1.0, 9)[:, None] * swing + c
            if _path_distance(a, path_xy).min() < cfg.clearance + half:
                return False
            return all(np.linalg.norm(a - pc, axis=1).min() > half + pr + 0.3 for pc, pr in placed)

        c = _crossing_spot(path_xy, fits)
        if c is None:  # no straight stretch looks across the motion: anywhere inside
            c = sample(True, half + cfg.moving_amplitude)
        else:
            placed.append((c, half + cfg.moving_amplitude))
        if c is not None:
            direction = MOVING_DIRECTION_W.copy()

            def clutter(wp: int, hp: int):
                # non-periodic: on a checker, KLT slips onto look-alike neighbouring corners
                return object_texture(wp, hp, mrng)

            yaw = float(np.arctan2(direction[1], direction[0]))  # long side along the motion
            crate(c, yaw, size, clutter, moving=True)

    # own stream: the ground does not change when objects are added or removed
    tex, st = ground_texture(GROUND_TILE_PX, np.random.default_rng([seed, 1]), GROUND_CELL_PX)
    origin = np.array([lo[0] - 40.0, lo[1] - 40.0, ground_height])
    ground_pts = _tile_landmarks(st, origin, lo - 25.0, hi + 25.0)
    world = World(ground_height, tex, GROUND_TEXEL_M, origin, solids, faces,
                  np.zeros((0, 3)), np.zeros(0, bool), direction, cfg.moving_amplitude,
                  cfg.moving_period_s)
    # ground landmarks hidden under a solid are useless
    n, d = world.planes_at(0.0)
    lifted = ground_pts + 0.01 * _UP
    inside = np.any(np.all(np.einsum("mpk,nk->nmp", n, lifted) <= d[None], axis=2), axis=1)
    ground_pts = ground_pts[~inside]
    world.landmarks_W = np.concatenate([*marks, ground_pts])
    world.landmark_moving = np.concatenate([*moving_mask, np.zeros(len(ground_pts))]) > 0.5
    return world


def _crossing_spot(path_xy: F64, fits: Callable[[F64], bool]) -> F64 | None:
    """Where a walker crosses the view: straight ahead of the first straight stretch of the path
    (M, 2) that heads across :data:`MOVING_DIRECTION_W`, beyond its end, at the nearest spot
    ``fits(c)`` accepts (None if there is none). Seen head-on for the whole stretch,
    the object's motion is then almost perpendicular to the line of sight."""
    seg = np.diff(path_xy, axis=0)
    length = np.linalg.norm(seg, axis=1)
    ok = length > 1e-9
    tangent = np.zeros_like(seg)
    tangent[ok] = seg[ok] / length[ok, None]
    step = float(np.median(length[ok])) if ok.any() else 0.0
    if step <= 0.0:
        return None
    look = max(1, round(10.0 / step))  # straight = same heading 10 m further on
    j = np.arange(len(tangent) - look)
    straight = (np.abs(tangent[j] @ MOVING_DIRECTION_W[:2]) < 0.2) & (
        np.einsum("nk,nk->n", tangent[j], tangent[j + look]) > 0.999)
    starts = np.nonzero(straight & ~np.r_[False, straight[:-1]])[0]
    for j in starts:  # one try per straight stretch, in flight order
        side = np.array([-tangent[j, 1], tangent[j, 0]])
        for dist in np.arange(10.0, 60.0, 1.0):
            for lateral in (0.0, 1.5, -1.5, 3.0, -3.0):
                c = path_xy[j] + dist * tangent[j] + lateral * side
                if fits(c):
                    return c
    return None


def _tile_landmarks(st: F64, origin_W: F64, lo: F64, hi: F64) -> F64:
    """Ground-tile corners (K, 2) repeated over [lo, hi] (2,) m as 3-D points (N, 3)."""
    period = GROUND_TILE_PX * GROUND_TEXEL_M
    xy_tile = origin_W[:2] + st * GROUND_TEXEL_M
    i0 = np.floor((lo - origin_W[:2]) / period).astype(int)
    i1 = np.ceil((hi - origin_W[:2]) / period).astype(int)
    out = []
    for i in range(i0[0], i1[0] + 1):
        for j in range(i0[1], i1[1] + 1):
            xy = xy_tile + period * np.array([i, j], dtype=float)
            keep = np.all((xy >= lo) & (xy <= hi), axis=1)
            out.append(xy[keep])
    xy = np.concatenate(out)
    return np.column_stack([xy, np.full(len(xy), origin_W[2])])
