"""Fisheye (equidistant, Kannala-Brandt) images of the village from the pinhole renderer.

The renderer draws planar faces by homographies, which only a pinhole camera has. A fisheye
image is therefore rendered as a wider pinhole view from the same pose, with the same focal
length (the fisheye's centre is not resampled to a coarser grid), large enough to hold every
fisheye pixel's ray, and remapped: each fisheye pixel ``(u, v)`` takes the pinhole pixel of its
ray (``geometry.distortion.equidistant_rays``), bilinear. Rays more than ``MAX_RAY_DEG`` from
the axis (beyond what a pinhole view can hold) stay black, like a real fisheye's vignette.

With :mod:`svains.sim.render` and :mod:`svains.sim.raster`, the only modules of ``svains.sim``
importing OpenCV (documented exception: the remap).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.geometry.distortion import equidistant_rays
from svains.sim.render import Renderer
from svains.sim.world import World

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

MAX_RAY_DEG = 75.0  # widest ray rendered (tan 75° = 3.7 focal lengths off the centre)


def fisheye_to_pinhole_map(
    fu: float, fv: float, cu: float, cv: float, coeffs: ArrayLike, width: int, height: int
) -> tuple[NDArray[np.float32], NDArray[np.float32], tuple[float, float, float, float]]:
    """For each fisheye pixel (H, W), the normalised pinhole coordinates ``x/z``, ``y/z`` of its
    ray (NaN beyond ``MAX_RAY_DEG``), and their extent ``(x_min, x_max, y_min, y_max)``."""
    u = (np.arange(width, dtype=float) - cu) / fu
    v = (np.arange(height, dtype=float) - cv) / fv
    xd = np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1)
    ray = equidistant_rays(xd, coeffs)
    ok = ray[..., 2] > np.cos(np.radians(MAX_RAY_DEG))
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(ok, ray[..., 0] / ray[..., 2], np.nan)
        y = np.where(ok, ray[..., 1] / ray[..., 2], np.nan)
    ext = (float(np.nanmin(x)), float(np.nanmax(x)), float(np.nanmin(y)), float(np.nanmax(y)))
    return x.astype(np.float32), y.astype(np.float32), ext


class FisheyeRenderer:
    """Renders grey fisheye images (H, W) uint8 of ``world`` for a camera with pinhole
    intrinsics ``(f, f, cu, cv)`` of ``rig`` (its size too) and equidistant ``coeffs``."""

    def __init__(self, world: World, rig: RectifiedStereo, coeffs: ArrayLike) -> None:
        f = rig.f
        x, y, (x0, x1, y0, y1) = fisheye_to_pinhole_map(
            f, f, rig.cu, rig.cv, coeffs, rig.width, rig.height
        )
        # The wide pinhole view: same focal length, principal point placed so that the rays'
        # extent (plus a 2-px border for bilinear sampling) fits.
        cu_w, cv_w = 2.0 - f * x0, 2.0 - f * y0
        w_w = int(np.ceil(f * (x1 - x0))) + 5
        h_w = int(np.ceil(f * (y1 - y0))) + 5
        wide = RectifiedStereo(f, cu_w, cv_w, rig.baseline, rig.R_B_C, rig.p_B_C, w_w, h_w)
        self.wide_rig = wide
        self._renderer = Renderer(world, wide)
        # NaN (beyond MAX_RAY_DEG) -> -1: outside the wide image, black with BORDER_CONSTANT.
        self._map_x = np.nan_to_num(f * x + cu_w, nan=-1.0).astype(np.float32)
        self._map_y = np.nan_to_num(f * y + cv_w, nan=-1.0).astype(np.float32)

    def render(self, R_W_C: F64, p_W_C: F64, t_s: float = 0.0) -> U8:
        """Fisheye image of the camera at ``R_W_C`` (3, 3), ``p_W_C`` (3,) m, time ``t_s``."""
        img = self._renderer.render_with_depth(R_W_C, p_W_C, t_s, full_depth=False)[0]
        return cv2.remap(img, self._map_x, self._map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)  # fmt: skip
