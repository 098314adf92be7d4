"""CPU renderer of the village: per-face perspective warps with an analytic z-buffer.

Why this design (measured with ``bench/bench_render.py``): every surface is planar, so a face
maps its texture to the image by one homography ``H = K [R u | R v | R o + t]`` and its inverse
depth is *affine* in the pixel, ``1/z = n_C·K⁻¹(u, v, 1) / d_C``. Each visible face is warped
(``cv2.warpPerspective``, bilinear) only inside its projected bounding box, masked by its
near-plane-clipped polygon and composited where its ``1/z`` beats the z-buffer: correct
occlusion in any drawing order, no GPU, no display. The ground is one infinite plane rendered
straight from a periodic tile (``BORDER_WRAP``) in depth bands, each band from the texture
pyramid level that matches its pixel footprint (no aliasing far away); far pixels fade into haze.

This is the only module of ``svains.sim`` allowed to import OpenCV (documented exception).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from numpy.typing import NDArray

from svains.geometry.camera import RectifiedStereo
from svains.sim.world import Face, World

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

Z_NEAR = 0.05  # m
HAZE_START = 30.0  # m
HAZE_FULL = 80.0  # m
SKY = 200.0


def _pyramid(tex: U8, levels: int, wrap: bool) -> list[U8]:
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


def _level_scale(level: int) -> F64:
    """Level-``level`` texel coords -> level-0 texel coords (pyrDown halves about centres)."""
    k = float(2**level)
    return np.array([[k, 0, 0.5 * (k - 1)], [0, k, 0.5 * (k - 1)], [0, 0, 1.0]])


def _clip_polygon_2d(poly: F64, a: F64, c: float) -> F64:
    """Part of convex polygon (K, 2) where ``a·x + c >= 0`` (Sutherland-Hodgman, one plane)."""
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
        self._ground = _pyramid(world.ground_texture, 6, wrap=True)
        # Each level padded by half a period on every side (wrap-around copy): a band whose
        # texture coordinates fit after shifting by whole periods is warped with the cheap
        # BORDER_REPLICATE instead of BORDER_WRAP (2.5x slower per pixel, measured).
        self._ground_pad = [np.pad(g, g.shape[0] // 2, mode="wrap") for g in self._ground]
        self._face_pyr: dict[int, list[U8]] = {}
        self._pool: ThreadPoolExecutor | None = None
        self.last_inv_depth: NDArray[np.float32] | None = None
        # per-face constants, stacked so culling is one vectorised pass per image
        faces = world.faces
        self._normals_W = np.array([f.normal_W for f in faces]).reshape(-1, 3)
        self._v0_W = np.array([f.vertices_W[0] for f in faces]).reshape(-1, 3)
        self._n_verts = np.array([len(f.vertices_W) for f in faces], dtype=int)
        pad = np.zeros((len(faces), 4, 3))
        for k, f in enumerate(faces):
            pad[k, : len(f.vertices_W)] = f.vertices_W
            pad[k, len(f.vertices_W):] = f.vertices_W[0]  # repeat: harmless for bounds
        self._verts_W = pad
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
        off = self.world.moving_offset_W(t_s)
        for idx in self._candidate_faces(R_C_W, t_C, p_W_C, off):
            shift = off if self._face_moving[idx] else None
            self._render_face(idx, self.world.faces[idx], img, zbuf, R_C_W, t_C, p_W_C, shift)
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
                z = 1.0 / zr
            fog = np.clip((z - HAZE_START) * (1.0 / (HAZE_FULL - HAZE_START)), 0.0, 1.0)
            band = img[r0:r1].astype(np.float32)
            band += fog * (self._sky[r0:r1] - band)
            img[r0:r1] = np.rint(band).astype(np.uint8)
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
        front = np.einsum("fk,fk->f", self._normals_W, p_W_C - self._v0_W - shift) > 1e-9
        v_C = np.einsum("ij,fkj->fki", R_C_W, self._verts_W + shift[:, None]) + t_C
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
        inv_lim = [np.inf] + [1.0 / z for z in z_lim] + [1.0 / (HAZE_FULL * 2.0)]
        rect = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
        coef = np.array([a, b])
        # far to near, each band's whole bounding box: a nearer band overwrites the overlap with
        # a sharper level of the same texture (no masks needed; sky pixels get hazed away)
        for lv in reversed(range(levels)):
            hi_inv, lo_inv = inv_lim[lv], inv_lim[lv + 1]
            poly = _clip_polygon_2d(rect, coef, c - lo_inv)
            if np.isfinite(hi_inv):
                poly = _clip_polygon_2d(poly, -coef, hi_inv - c)
            if len(poly) < 3:
                continue
            x0, y0 = np.floor(poly.min(0)).astype(int)
            x1, y1 = np.ceil(poly.max(0)).astype(int) + 1
            x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
            if x1 <= x0 or y1 <= y0:
                continue
            T = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
            M = np.linalg.inv(T @ H0 @ _level_scale(lv))
            src, border = self._ground[lv], cv2.BORDER_WRAP
            corners = np.array([[0, 0, 1], [x1 - x0, 0, 1], [0, y1 - y0, 1],
                                [x1 - x0, y1 - y0, 1]], float) @ M.T
            if np.all(corners[:, 2] > 1e-9):
                st = corners[:, :2] / corners[:, 2:]
                period = src.shape[0]
                pad = period // 2
                k = np.floor(st.min(0) / period)
                lo_st = st.min(0) - k * period
                hi_st = st.max(0) - k * period
                if np.all(lo_st >= 0) and np.all(hi_st < period + pad - 2):
                    sh = pad - k * period
                    M = np.array([[1.0, 0, sh[0]], [0, 1.0, sh[1]], [0, 0, 1.0]]) @ M
                    src, border = self._ground_pad[lv], cv2.BORDER_REPLICATE
            cv2.warpPerspective(
                src, M, (x1 - x0, y1 - y0), dst=img[y0:y1, x0:x1],
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=border,
            )
        return a, b, c

    def _render_face(
        self, idx: int, face: Face, img: U8, zbuf: NDArray[np.float32],
        R_C_W: F64, t_C: F64, p_W_C: F64, shift: F64 | None,
    ) -> None:
        verts = face.vertices_W if shift is None else face.vertices_W + shift
        origin = face.origin_W if shift is None else face.origin_W + shift
        n_W = self._normals_W[idx]
        v_C = verts @ R_C_W.T + t_C
        if v_C[:, 2].min() < Z_NEAR:
            v_C = _clip_polygon_2d(v_C, np.array([0.0, 0.0, 1.0]), -Z_NEAR)
        rig = self.rig
        u = v_C[:, 0] / v_C[:, 2] * rig.f + rig.cu
        v = v_C[:, 1] / v_C[:, 2] * rig.f + rig.cv
        x0, x1 = max(math.floor(u.min()), 0), min(math.ceil(u.max()) + 1, rig.width)
        y0, y1 = max(math.floor(v.min()), 0), min(math.ceil(v.max()) + 1, rig.height)
        if x1 <= x0 or y1 <= y0:
            return
        n_C = R_C_W @ n_W
        a, b, c = self._inv_depth(n_C, float(n_C @ v_C[0]))
        iz = self._uu[:, x0:x1] * np.float32(a) + (self._vv[y0:y1] * np.float32(b)
                                                   + np.float32(c))
        visible = iz > zbuf[y0:y1, x0:x1]
        if not visible.any():
            return
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        pts = np.rint(np.column_stack([u - x0, v - y0]) * 16.0).astype(np.int32)  # 4 frac bits
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
        np.logical_and(visible, mask.view(bool), out=visible)
        if not visible.any():
            return
        # pyramid level from the face's footprint at its centroid (geometric mean over slant)
        texel = float(np.linalg.norm(face.u_W))
        centre = v_C.mean(0)
        cos = abs(float(n_C @ centre)) / float(np.linalg.norm(centre))
        foot = centre[2] / (self.rig.f * np.sqrt(max(cos, 1e-3)))
        pyr = self._face_pyr.get(idx)
        if pyr is None:
            pyr = self._face_pyr[idx] = _pyramid(face.texture, 4, wrap=False)
        lv = int(np.clip(np.floor(np.log2(max(foot / texel, 1.0))), 0, len(pyr) - 1))
        H0 = self.K @ np.column_stack(
            [R_C_W @ face.u_W, R_C_W @ face.v_W, R_C_W @ origin + t_C]
        )
        T = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
        M = np.linalg.inv(T @ H0 @ _level_scale(lv))
        patch = cv2.warpPerspective(
            pyr[lv], M, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
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
        out += np.float32(noise_std) * unit
    # values stay >= 0 after rounding except for noise on black, which abs() mirrors harmlessly
    return cv2.convertScaleAbs(out, alpha=float(gain))
