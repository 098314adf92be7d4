"""Ideal (rectified) pinhole stereo rig, the camera model every vision model sees.

Camera frame: x right, y down, z forward. Pixels ``uv`` = (column, row). The right camera sits at
``(baseline, 0, 0)`` in left-camera components with the same orientation (paper: ``b``).
``R_B_C``/``p_B_C`` place the rectified left camera on the body (the paper's ``C`` and ``c_B``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class RectifiedStereo:
    """Rectified stereo pair: focal ``f`` px, principal point ``(cu, cv)`` px, ``baseline`` m,
    left camera pose on the body ``R_B_C`` (3, 3), ``p_B_C`` (3,) m, image size px."""

    f: float
    cu: float
    cv: float
    baseline: float
    R_B_C: F64
    p_B_C: F64
    width: int
    height: int

    @property
    def K(self) -> F64:
        return np.array([[self.f, 0.0, self.cu], [0.0, self.f, self.cv], [0.0, 0.0, 1.0]])

    def project(self, p_C: ArrayLike) -> F64:
        """Left-image pixels of camera points ``p_C`` (..., 3) -> (..., 2)."""
        p = np.asarray(p_C, dtype=float)
        z = p[..., 2]
        return np.stack([self.f * p[..., 0] / z + self.cu, self.f * p[..., 1] / z + self.cv], -1)

    def project_right(self, p_C: ArrayLike) -> F64:
        """Right-image pixels of left-camera points ``p_C`` (..., 3) -> (..., 2)."""
        p = np.array(p_C, dtype=float)
        p[..., 0] -= self.baseline
        return self.project(p)

    def triangulate(self, uv_left: ArrayLike, uv_right: ArrayLike) -> F64:
        """Eq. 10: left-camera points (..., 3) m from rectified left/right pixels (..., 2).

        Disparity ``u_left - u_right`` must be positive; non-positive disparities give NaN.
        """
        uvl = np.asarray(uv_left, dtype=float)
        uvr = np.asarray(uv_right, dtype=float)
        disparity = uvl[..., 0] - uvr[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(disparity > 0, self.f * self.baseline / disparity, np.nan)
        x = (uvl[..., 0] - self.cu) * z / self.f
        y = (uvl[..., 1] - self.cv) * z / self.f
        return np.stack([x, y, z], axis=-1)

    def in_image(self, uv: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """True where pixels (..., 2) lie inside the image, ``margin`` px from the border."""
        uv = np.asarray(uv, dtype=float)
        return (
            (uv[..., 0] >= margin)
            & (uv[..., 0] <= self.width - 1 - margin)
            & (uv[..., 1] >= margin)
            & (uv[..., 1] <= self.height - 1 - margin)
        )
