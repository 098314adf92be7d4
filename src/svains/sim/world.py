"""The village: textured ground plane and convex textured solids (houses, roofs, crates, poles)
laid out around the flight path, and the landmarks (texture corners lifted to 3-D).

The solids, their faces and the ray casting on them are in :mod:`svains.sim.solids`; this module
places them (:func:`build_world`). Pure numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
from numpy.typing import NDArray

from svains.sim.config import WorldConfig
from svains.sim.solids import (
    MOVING_DIRECTION_W,
    MOVING_SHARPNESS,
    Face,
    Solid,
    TextureMaker,
    World,
    add_box,
    box_corners,
    make_face,
    planes_from_faces,
)
from svains.sim.textures import (
    band_texture,
    checker_texture,
    ground_tile,
    object_texture,
    roof_texture,
    wall_texture,
)

# Re-exported: the renderer, sensors and tests import the world types from here.
__all__ = [
    "GROUND_CELL_PX", "GROUND_TEXEL_M", "GROUND_TILE_PX", "MOVING_DIRECTION_W", "MOVING_SHARPNESS",
    "WALL_TEXEL_M", "Face", "Solid", "World", "build_world",
]  # fmt: skip

F64 = NDArray[np.float64]

WALL_TEXEL_M = 0.02
GROUND_TEXEL_M = 0.01
GROUND_TILE_PX = 2048
GROUND_CELL_PX = 110
_UP = np.array([0.0, 0.0, 1.0])


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
        corners = box_corners(c, (w, d, h), yaw, ground_height)
        sid = len(solids)

        def wall(wp: int, hp: int):
            return wall_texture(wp, hp, rng, WALL_TEXEL_M, windows=True)

        fs, pts = add_box(faces, corners, sid, wall, None, WALL_TEXEL_M)
        top = corners[4:]
        solids.append(planes_from_faces(fs, [(np.array([0, 0, 1.0]), ground_height + h),
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
            make_face(np.array([r0, r1, top[1], top[0]]), WALL_TEXEL_M, rid, roof)[0],
            make_face(np.array([r1, r0, top[3], top[2]]), WALL_TEXEL_M, rid, roof)[0],
        ]
        # gable triangles: texture spans the triangle's bounding rectangle
        for a, b, r in ((top[1], top[2], r1), (top[3], top[0], r0)):
            f, _ = make_face(np.array([a + rh * _UP, b + rh * _UP, b, a]), WALL_TEXEL_M, rid,
                             gable)
            f.vertices_W = np.array([r, b, a])
            roof_faces.append(f)
        faces.extend(roof_faces)
        roof_floor = (np.array([0, 0, -1.0]), -(ground_height + h))
        solids.append(planes_from_faces(roof_faces, [roof_floor]))

    def crate(c: F64, yaw: float, size: tuple[float, float, float] | None = None,
              tex: TextureMaker | None = None, moving: bool = False) -> None:
        if size is None:
            size = (rng.uniform(0.8, 2.0), rng.uniform(0.8, 2.0), rng.uniform(0.8, 2.0))
        corners = box_corners(c, size, yaw, ground_height)
        if tex is None:
            tex = partial(checker_texture, rng=rng, square_px=int(rng.integers(10, 16)))
        fs, pts = add_box(faces, corners, len(solids), tex, tex, WALL_TEXEL_M)
        s = planes_from_faces(fs, [(np.array([0, 0, -1.0]), -ground_height)])
        s.moving = moving
        solids.append(s)
        marks.append(pts)
        moving_mask.append(np.full(len(pts), 1.0 if moving else 0.0))

    def pole(c: F64) -> None:
        corners = box_corners(c, (0.25, 0.25, rng.uniform(3.0, 5.0)), rng.uniform(0, np.pi), 0.0)
        corners[:, 2] += ground_height

        def bands(wp: int, hp: int):
            return band_texture(wp, hp, 25)

        fs, _ = add_box(faces, corners, len(solids), bands, bands, WALL_TEXEL_M)
        solids.append(planes_from_faces(fs, [(np.array([0, 0, -1.0]), -ground_height)]))

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
    tex, st = ground_tile(GROUND_TILE_PX, np.random.default_rng([seed, 1]), GROUND_CELL_PX)
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
