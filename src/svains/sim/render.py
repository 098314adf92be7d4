"""CPU renderer of the village: per-face perspective warps with an analytic z-buffer.

Why this design (measured with ``bench/bench_render.py``): every surface is planar, so a face
maps its texture to the image by one homography ``H = K [R u | R v | R o + t]`` and its inverse
depth is *affine* in the pixel, ``1/z = n_C·K⁻¹(u, v, 1) / d_C``. Each visible face is warped
(``cv2.warpPerspective``, bilinear) only inside its projected bounding box, masked by its
near-plane-clipped polygon and composited where its ``1/z`` beats the z-buffer: correct
occlusion in any drawing order, no GPU, no display. The ground is one infinite plane rendered
from a periodic tile in depth bands, each band from the texture pyramid level that matches its
pixel footprint (no aliasing far away); far pixels fade into haze.

Speed (about 8 ms of one core per 752x480 image, ~16 ms per stereo pair, was ~12 and ~24):
OpenCV's warp costs 20-45 ns per pixel with ``BORDER_WRAP`` or where ``BORDER_REPLICATE``
samples outside the source, 5-8 ns otherwise. So the ground bands sample a copy of each level
tiled to GROUND_TILE_SIDE, shifted by whole periods (``BORDER_TRANSPARENT`` beyond it), and
face textures carry a replicated border so ``BORDER_CONSTANT`` is safe whenever the face's
1-px hull maps inside (checked per face). The per-face set-up (clipping, boxes, levels, warp
matrices) is vectorised over faces in :mod:`svains.sim.raster`.

With :mod:`svains.sim.raster`, the only modules of ``svains.sim`` importing OpenCV
(documented exception).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from numpy.typing import NDArray

from svains.geometry.camera import RectifiedStereo
from svains.sim.raster import (
    clip_polygon_2d,
    face_setup,
    face_table,
    level_scale,
    padded_face_pyramid,
    pyramid,
    tile,
)
from svains.sim.world import World

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

Z_NEAR = 0.05  # m
HAZE_START = 30.0  # m
HAZE_FULL = 80.0  # m
SKY = 200.0
GROUND_TILE_SIDE = 1536  # texels: every ground band of the default camera fits (measured)


class Renderer:
    """Renders grey images (H, W) uint8 of ``world`` through the left/right camera of ``rig``."""

    def __init__(self, world: World, rig: RectifiedStereo) -> None:
        self.world = world
        self.rig = rig
        self.K = rig.K
        self.K_inv = np.linalg.inv(self.K)
        h, w = rig.height, rig.width
        self._uu = np.arange(w, dtype=np.float32)[None, :]
        self._vv = np.arange(h, dtype=np.float32)[:, None]
        self._ground = pyramid(world.ground_texture, 6, wrap=True)
        # Each level tiled periodically to GROUND_TILE_SIDE (at least 2 periods): a band whose
        # texture coordinates fit after a shift by whole periods is warped from it with
        # BORDER_TRANSPARENT, 5-10x cheaper per pixel than BORDER_WRAP (measured).
        self._ground_tiled = [tile(g, max(GROUND_TILE_SIDE, 2 * g.shape[0]))
                              for g in self._ground]
        self._face_pyr: dict[int, list[U8]] = {}
        self._pool: ThreadPoolExecutor | None = None
        self.last_inv_depth: NDArray[np.float32] | None = None
        # per-face constants, stacked so culling and set-up are vectorised passes per image
        faces = world.faces
        self._normals_W = np.array([f.normal_W for f in faces]).reshape(-1, 3)
        self._v0_W = np.array([f.vertices_W[0] for f in faces]).reshape(-1, 3)
        self._table = face_table(faces)
        self._verts_W = self._table.verts_W
        moving = [k for k, s in enumerate(world.solids) if s.moving]
        self._face_moving = np.array([f.solid in moving for f in faces], dtype=bool)
        sky_rows = SKY - 25.0 * (1.0 - np.arange(h) / h)
        self._sky = np.repeat(sky_rows[:, None], w, axis=1).astype(np.float32)

    def _inv_depth(self, n_C: F64, d_C: float) -> tuple[float, float, float]:
        """Coefficients (a, b, c) with ``1/z = a u + b v + c`` for the plane ``n_C·X = d_C``."""
        coef = (n_C @ self.K_inv) / d_C
        return float(coef[0]), float(coef[1]), float(coef[2])

    def render(self, R_W_C: F64, p_W_C: F64, t_s: float = 0.0) -> U8:
        """Noise-free image (H, W) uint8 of the camera at ``R_W_C`` (3, 3), ``p_W_C`` (3,).

        ``self.last_inv_depth`` keeps the image's inverse depth (H, W) 1/m (0 = sky)."""
        img, self.last_inv_depth = self.render_with_depth(R_W_C, p_W_C, t_s)
        return img

    def render_with_depth(
        self, R_W_C: F64, p_W_C: F64, t_s: float = 0.0, full_depth: bool = True
    ) -> tuple[U8, NDArray[np.float32] | None]:
        """Image (H, W) uint8 and, if ``full_depth``, its inverse depth (H, W) 1/m. Thread-safe
        (no state but the texture-pyramid cache, whose concurrent fills are idempotent)."""
        R_C_W = R_W_C.T
        t_C = -R_C_W @ p_W_C
        h, w = self.rig.height, self.rig.width
        img = np.empty((h, w), np.uint8)
        ground = self._render_ground(img, R_C_W, t_C, p_W_C)
        # Objects stand on the ground and the camera flies above it, so the ground never hides
        # a face: the z-buffer holds faces only (0 = no face yet) and the ground's 1/z, affine
        # in the pixel, is evaluated only where it is needed (haze rows, depth output).
        zbuf = np.zeros((h, w), np.float32)
        self._draw_faces(img, zbuf, R_C_W, t_C, p_W_C, self.world.moving_offset_W(t_s))
        # haze: fade far pixels to the sky brightness (hides minified far detail, as air does);
        # only rows where the ground (or the sky) is farther than HAZE_START are touched: an
        # object point above the ground is never below the ground line of its own depth
        if ground is None:
            r0, r1 = 0, h
        else:
            a, b, c = ground
            vv = self._vv[:, 0]
            row_min = np.minimum(b * vv + c, a * (w - 1) + b * vv + c)
            rows = np.nonzero(row_min < 1.0 / HAZE_START)[0]
            r0, r1 = (rows[0], rows[-1] + 1) if len(rows) else (0, 0)
        if r1 > r0:
            zr = self._combined_depth(zbuf, ground, r0, r1)
            with np.errstate(divide="ignore"):
                fog = np.divide(1.0, zr, out=zr)  # z (inf = sky), in place: fewer passes
            fog -= HAZE_START
            fog *= 1.0 / (HAZE_FULL - HAZE_START)
            np.clip(fog, 0.0, 1.0, out=fog)
            band = img[r0:r1].astype(np.float32)
            sky = self._sky[r0:r1] - band
            sky *= fog
            band += sky
            cv2.convertScaleAbs(band, dst=img[r0:r1])  # rounds half to even like np.rint
        return img, self._combined_depth(zbuf, ground, 0, h) if full_depth else None

    def _combined_depth(
        self, zbuf: NDArray[np.float32], ground: tuple[float, float, float] | None, r0: int,
        r1: int,
    ) -> NDArray[np.float32]:
        """Inverse depth of rows ``r0:r1``: the face z-buffer where a face is drawn, else the
        ground's analytic 1/z (0 above the horizon)."""
        faces = zbuf[r0:r1]
        if ground is None:
            return faces.copy()
        a, b, c = ground
        g = self._uu * np.float32(a) + (self._vv[r0:r1] * np.float32(b) + np.float32(c))
        np.maximum(g, 0.0, out=g)
        return np.where(faces > 0, faces, g)

    def _candidate_faces(self, R_C_W: F64, t_C: F64, p_W_C: F64, off: F64) -> NDArray[np.int_]:
        """Faces that are front-facing, partly beyond the near plane and not entirely outside
        the image (conservative test on the vertices in front of the camera)."""
        if len(self._v0_W) == 0:
            return np.zeros(0, int)
        shift = np.where(self._face_moving[:, None], off[None], 0.0)
        front = (self._normals_W * (p_W_C - self._v0_W - shift)).sum(axis=1) > 1e-9
        v_C = (self._verts_W + shift[:, None]) @ R_C_W.T + t_C
        z = v_C[..., 2]
        any_front = (z > Z_NEAR).any(axis=1)
        all_front = (z > Z_NEAR).all(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = v_C[..., :2] / np.maximum(z, Z_NEAR)[..., None] * self.rig.f
        uv += [self.rig.cu, self.rig.cv]
        outside = (
            (uv[..., 0].max(1) < 0)
            | (uv[..., 0].min(1) > self.rig.width)
            | (uv[..., 1].max(1) < 0)
            | (uv[..., 1].min(1) > self.rig.height)
        )
        # faces crossing the near plane are always kept (their projection is unbounded)
        keep = np.nonzero(front & any_front & (~all_front | ~outside))[0]
        # near to far: faces hidden behind nearer ones then fail the z-test before any warp
        return keep[np.argsort(z[keep].min(axis=1))]

    def _render_ground(
        self, img: U8, R_C_W: F64, t_C: F64, p_W_C: F64
    ) -> tuple[float, float, float] | None:
        """Draw the ground plane into ``img``; return its ``1/z = a u + b v + c`` coefficients
        (None when the camera is not above the ground)."""
        world = self.world
        w, h = self.rig.width, self.rig.height
        height = p_W_C[2] - world.ground_height
        if height <= 0.01:
            img[:] = self._sky.astype(np.uint8)
            return None
        n_C = R_C_W @ np.array([0.0, 0.0, 1.0])
        a, b, c = self._inv_depth(n_C, world.ground_height - p_W_C[2])
        img[:] = SKY  # pixels no band reaches are far: the haze turns them into sky anyway
        tau = world.ground_texel_m
        H0 = self.K @ np.column_stack(
            [R_C_W[:, 0] * tau, R_C_W[:, 1] * tau, R_C_W @ world.ground_origin_W + t_C]
        )
        # band limits: the geometric-mean footprint of the slanted ground, z^1.5 / (f √height),
        # equals one texel of level L at z_L = (f √height τ 2^L)^(2/3)
        levels = len(self._ground)
        z_lim = [(self.rig.f * np.sqrt(height) * tau * 2.0**lv) ** (2.0 / 3.0)
                 for lv in range(1, levels)]
        # beyond HAZE_FULL the haze replaces every pixel by the sky: no band needed there
        inv_lim = [np.inf] + [1.0 / z for z in z_lim] + [1.0 / HAZE_FULL]
        rect = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
        coef = np.array([a, b])
        # far to near, each band's whole bounding box: a nearer band overwrites the overlap with
        # a sharper level of the same texture (no masks needed; sky pixels get hazed away)
        for lv in reversed(range(levels)):
            hi_inv, lo_inv = inv_lim[lv], inv_lim[lv + 1]
            poly = clip_polygon_2d(rect, coef, c - lo_inv)
            if np.isfinite(hi_inv):
                poly = clip_polygon_2d(poly, -coef, hi_inv - c)
            if len(poly) < 3:
                continue
            x0, y0 = np.floor(poly.min(0)).astype(int)
            x1, y1 = np.ceil(poly.max(0)).astype(int) + 1
            x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
            if x1 <= x0 or y1 <= y0:
                continue
            T = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
            M = np.linalg.inv(T @ H0 @ level_scale(lv))
            self._warp_ground_band(img, lv, M, x0, y0, x1, y1, poly)
        return a, b, c

    def _warp_ground_band(
        self, img: U8, lv: int, M: F64, x0: int, y0: int, x1: int, y1: int, band: F64
    ) -> None:
        """Warp ground level ``lv`` into ``img[y0:y1, x0:x1]``; ``M`` maps box pixels to level
        texels, ``band`` (K, 2) is the band's polygon in image pixels. When the band fits in
        the tiled level after a shift by whole periods, BORDER_TRANSPARENT leaves the box
        pixels beyond the tile as they are (farther: drawn by a coarser band; nearer: drawn
        next; above the horizon: hazed to sky), else BORDER_WRAP (5-10x slower per pixel)."""
        dst = img[y0:y1, x0:x1]
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        hom = (band - [x0, y0]) @ M[:, :2].T + M[:, 2]
        if np.all(hom[:, 2] > 1e-9):
            st = hom[:, :2] / hom[:, 2:]
            period = self._ground[lv].shape[0]
            tiled = self._ground_tiled[lv]
            k = np.floor((st.min(0) - 2.0) / period)  # >= 2 texels of margin (bilinear)
            if np.all(st.max(0) - k * period < tiled.shape[0] - 3.0):
                sh = -k * period
                M = np.array([[1.0, 0, sh[0]], [0, 1.0, sh[1]], [0, 0, 1.0]]) @ M
                cv2.warpPerspective(tiled, M, dst.shape[::-1], dst=dst, flags=flags,
                                    borderMode=cv2.BORDER_TRANSPARENT)
                return
        cv2.warpPerspective(self._ground[lv], M, dst.shape[::-1], dst=dst, flags=flags,
                            borderMode=cv2.BORDER_WRAP)

    def _face_pyramid(self, idx: int) -> list[U8]:
        """Padded texture pyramid of face ``idx``, built at first use (idempotent fill)."""
        pyr = self._face_pyr.get(idx)
        if pyr is None:
            pyr = self._face_pyr[idx] = padded_face_pyramid(self.world.faces[idx].texture)
        return pyr

    def _draw_faces(
        self, img: U8, zbuf: NDArray[np.float32], R_C_W: F64, t_C: F64, p_W_C: F64, off: F64
    ) -> None:
        """Draw every candidate face into ``img`` where it beats ``zbuf`` (both updated).
        The set-up is vectorised over faces; each face costs one warp over its bounding box,
        masked by its polygon and the z-test; faces crossing the near plane are clipped."""
        order = self._candidate_faces(R_C_W, t_C, p_W_C, off)
        if len(order) == 0:
            return
        shift = np.where(self._face_moving[order, None], off[None], 0.0)
        fs = face_setup(self._table, order, shift, R_C_W, t_C, self.K, self.K_inv,
                        (self.rig.width, self.rig.height), Z_NEAR)
        iz_coef = fs.inv_depth.astype(np.float32)
        for k, (idx, box) in enumerate(zip(order.tolist(), fs.box.tolist(), strict=True)):
            x0, y0, x1, y1 = box
            if x1 <= x0 or y1 <= y0:
                continue
            a, b, c = iz_coef[k]
            iz = self._uu[:, x0:x1] * a + (self._vv[y0:y1] * b + c)
            visible = iz > zbuf[y0:y1, x0:x1]
            if not visible.any():
                continue
            mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
            pts = np.rint((fs.uv[k] - [x0, y0]) * 16.0).astype(np.int32)  # 4 frac bits
            cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
            np.logical_and(visible, mask.view(bool), out=visible)
            if not visible.any():
                continue
            patch = cv2.warpPerspective(
                self._face_pyramid(idx)[fs.level[k]], fs.M[k], (x1 - x0, y1 - y0),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT if fs.constant_border[k] else
                cv2.BORDER_REPLICATE,
            )
            np.copyto(img[y0:y1, x0:x1], patch, where=visible)
            np.copyto(zbuf[y0:y1, x0:x1], iz, where=visible)

    def render_pair(
        self, R_W_B: F64, p_W_B: F64, t_s: float = 0.0
    ) -> tuple[U8, U8]:
        """Noise-free left and right images for the body pose ``R_W_B``, ``p_W_B``."""
        R_W_C = R_W_B @ self.rig.R_B_C
        p_W_C0 = p_W_B + R_W_B @ self.rig.p_B_C
        p_W_C1 = p_W_C0 + R_W_C[:, 0] * self.rig.baseline
        # left and right in two threads: OpenCV and the big numpy operations release the GIL
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=2)
        right = self._pool.submit(self.render_with_depth, R_W_C, p_W_C1, t_s, False)
        left = self.render_with_depth(R_W_C, p_W_C0, t_s, False)[0]
        return left, right.result()[0]


class NoiseBank:
    """Pre-drawn unit Gaussian noise: ``n_fields`` fields (H + pad, W + pad) float32; each image
    takes a window at a random field and offset (16k distinct windows at the defaults). Drawing
    361k fresh normals per image cost 7 ms, half the render time (measured); 2-grey-level
    noise that repeats shifted between frames forms no trackable structure."""

    def __init__(self, shape: tuple[int, int], rng: np.random.Generator, n_fields: int = 4,
                 pad: int = 64) -> None:
        self.shape = shape
        self.pad = pad
        self.rng = rng
        self.fields = rng.standard_normal((n_fields, shape[0] + pad, shape[1] + pad),
                                          dtype=np.float32)

    def draw(self) -> NDArray[np.float32]:
        k, dy, dx = self.rng.integers(0, [len(self.fields), self.pad, self.pad])
        return self.fields[k, dy : dy + self.shape[0], dx : dx + self.shape[1]]


def finish_image(
    img: U8, gain: float, noise_std: float, rng: np.random.Generator,
    bank: NoiseBank | None = None,
) -> U8:
    """Exposure ``gain``, additive Gaussian grey-level noise (std in grey levels), saturated to
    uint8. With a ``bank`` the noise comes from it (fast); otherwise it is drawn from ``rng``."""
    out = img.astype(np.float32)
    if noise_std > 0:
        unit = bank.draw() if bank is not None else rng.standard_normal(img.shape, np.float32)
        cv2.scaleAdd(unit, float(noise_std), out, dst=out)  # fused: 5x faster than numpy
    # values stay >= 0 after rounding except for noise on black, which abs() mirrors harmlessly
    return cv2.convertScaleAbs(out, alpha=float(gain))
