"""The ``tc``/``3d`` update with each feature's point marginalised (``vision.two_view``).

``PixelUpdater`` hands over the 8 tracked pixels of each feature (k-1 and k stereo pairs) and
the camera motion k-1 -> k of every sigma point and of the mean (``models.vision_two_view``):

1. the point is refined by Gauss-Newton over its 8 pixels at the mean motion (start: the k-1
   stereo point). When the mean motion explains the pixels poorly (the median feature's
   refined residual beyond ``WIDE_MISFIT``: a prior metres wide after a long gap), the frame's
   own egomotion is tried as well and the motion with the smaller misfit is taken. Points
   refined at a motion 0.37 m off carry that error into the null spaces: the update then moved
   the state away from the truth (0.37 -> 0.60 m on ``tests/test_vision_updater.py``'s frame;
   at the true motion: 0.008 m);
2. each feature's 8 residuals (tracked minus predicted pixels) are projected onto the left null
   space of the point Jacobian (5 numbers, noise ``σ² I`` since the basis is orthonormal). The
   block's measurement is 0 and ``h`` returns the projected negative residuals, so an iterated
   update (``filter.iterated``) refines the points and their null spaces again at each new
   linearisation point (the sigma points' centre, ``X[0]``, or the egomotion, whichever fits
   better);
3. the features are gated on those 5 numbers; the kept ones form one whitened block.

The projection removes the point's error to first order, so the k-1 stereo noise no longer sits
in the regressor of the fused translation (the paper's ``3d``, and ``tc`` whose transfer gives
the same prediction in a rectified pair, are attenuated by it).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.geometry.camera import RectifiedStereo
from svains.models.vision_two_view import (
    NUM_FUSED,
    inverse_depth,
    null_space,
    point_jacobian,
    refine_points,
    two_view_pixels,
)
from svains.navigation.vision_noise import feature_gate

F64 = NDArray[np.float64]
MotionFn = Callable[[F64], tuple[F64, F64]]
Motion = tuple[F64, F64]  # one camera motion k-1 -> k: R_c (3, 3), r_c (3,) m
Linearisation = tuple[F64, NDArray[np.bool_], F64]  # points (M, 3), valid (M,), N (M, 8, 5)
_FAR_RHO = 1e-3  # 1/m, stand-in point (1 km ahead) for a feature whose refinement failed
# Median over the features of the refined pixel residual's squared norm over σ²: about 5 (the
# χ² of its 5 dof) at the right motion; beyond the χ²(5) 0.99 quantile the motion is off.
WIDE_MISFIT = 15.09


@dataclass
class TwoViewFeatures:
    """One frame's features in the two-view form: ``Y`` (S, 5M) the sigma points' projected
    predictions minus the tracked pixels, ``z`` (5M,) zeros, ``R_blocks`` (M, 5, 5), the
    null-space bases ``N`` (M, 8, 5), the refined points ``a_F`` (M, 3) (inverse depth at k-1),
    ``valid`` (M,) (refinement converged in front of both cameras), the tracked pixels
    ``z8`` (M, 8) and ``alternative``, the frame's own egomotion when it was needed (the mean
    motion fitted the pixels poorly). The camera motion comes from the k-1 frame's pose clone,
    so no IMU increment noise enters (``rotation="imu"`` is refused)."""

    Y: F64
    z: F64
    R_blocks: F64
    N: F64
    a_F: F64
    valid: NDArray[np.bool_]
    rig: RectifiedStereo
    z8: F64
    sigma_px: float
    alternative: Motion | None = None

    @classmethod
    def build(
        cls, R_all: F64, r_all: F64, z8: F64, p_Ckm1_F: F64, rig: RectifiedStereo,
        sigma_px: float, egomotion: Callable[[], Motion | None] | None = None,
    ) -> TwoViewFeatures:
        """``R_all`` (S+1, 3, 3), ``r_all`` (S+1, 3): camera motion of the sigma points, the
        mean last; ``z8`` (M, 8) px tracked pixels; ``p_Ckm1_F`` (M, 3) m the k-1 stereo
        points; ``sigma_px`` one pixel's noise; ``egomotion`` gives the frame's own camera
        motion (None: none), asked for only when the mean motion fits the pixels poorly."""
        a0 = inverse_depth(p_Ckm1_F)
        lin = _linearised(a0, z8, R_all[-1], r_all[-1], rig)
        alternative = None
        if egomotion is not None:
            own = _misfit(lin, z8, R_all[-1], r_all[-1], rig, sigma_px)
            if own > WIDE_MISFIT and (alternative := egomotion()) is not None:
                lin = _better(lin, own, _fit(a0, z8, alternative, rig, sigma_px))
        a, valid, N = lin
        Y = _projected(N, two_view_pixels(R_all[:-1], r_all[:-1], a, rig), z8)
        M = z8.shape[0]
        z = np.zeros(M * NUM_FUSED)
        R_blocks = np.broadcast_to(sigma_px**2 * np.eye(NUM_FUSED), (M, NUM_FUSED, NUM_FUSED))
        return cls(Y, z, np.ascontiguousarray(R_blocks), N, a, valid, rig, z8, sigma_px,
                   alternative)  # fmt: skip

    def gate(
        self, points: MerweScaledSigmaPoints, probability: float | None
    ) -> tuple[NDArray[np.bool_], NDArray[np.bool_], F64]:
        """(keep (M,), finite (M,), NIS (M,)): ``vision_noise.feature_gate`` on the 5 numbers,
        and only features whose point refinement succeeded."""
        keep, finite, nis = feature_gate(self.Y, points.Wm, points.Wc, self.z, self.R_blocks,
                                         probability)  # fmt: skip
        finite &= self.valid
        return keep & self.valid, finite, nis

    def model(self, kept: NDArray[np.int64], motion: MotionFn) -> Callable[[F64], F64]:
        """``h(X)`` (S, 5K) of the kept features for any sigma points ``X`` (S, nx) (iterated
        updates): points and null spaces linearised again at the motion of ``X[0]``."""
        a0, z8, rig, alt = self.a_F[kept], self.z8[kept], self.rig, self.alternative
        sigma_px = self.sigma_px
        # The linearisation at the egomotion and its misfit are the same at every call (same
        # points, same motion): made once, when first needed (an iterated update calls ``h`` up
        # to six times per frame, and refining the points is most of a call).
        alt_fit = None if alt is None else functools.cache(
            lambda: _fit(a0, z8, alt, rig, sigma_px))

        def h(X: F64) -> F64:
            R_c, r_c = motion(X)
            lin = _linearised(a0, z8, R_c[0], r_c[0], rig)
            if alt_fit is not None:
                # Near the posterior the state's own motion is kept: the egomotion, fitted to
                # the pixels alone, always fits them a little better.
                own = _misfit(lin, z8, R_c[0], r_c[0], rig, sigma_px)
                if own > WIDE_MISFIT:
                    lin = _better(lin, own, alt_fit())
            a, _, N = lin
            return _projected(N, two_view_pixels(R_c, r_c, a, rig), z8)

        return h


def _linearised(a0: F64, z8: F64, R_c: F64, r_c: F64, rig: RectifiedStereo) -> Linearisation:
    """Points refined from ``a0`` (M, 3) over the pixels ``z8`` (M, 8) at the camera motion
    ``R_c`` (3, 3), ``r_c`` (3,): (points (M, 3), valid (M,), null spaces (M, 8, 5)). A point
    whose refinement failed or lies behind either camera is invalid (and replaced by a far
    stand-in so the bases stay finite)."""
    a = refine_points(a0, z8, R_c, r_c, rig)
    valid = np.isfinite(a).all(axis=1) & (a[:, 2] > 0.0)
    a = np.where(valid[:, None], a, [0.0, 0.0, _FAR_RHO])
    q_z = R_c[2, 2] - a[:, 2] * r_c[2] + a[:, :2] @ R_c[2, :2]
    valid &= q_z > 0.0  # in front of the camera at k too
    return a, valid, null_space(point_jacobian(R_c, r_c, a, rig))


def _misfit(
    lin: Linearisation, z8: F64, R_c: F64, r_c: F64, rig: RectifiedStereo, sigma_px: float
) -> float:
    """Median over the features of ``|z8 - pixels|² / σ²`` at the points ``lin`` refined for
    the motion ``R_c``, ``r_c`` (an invalid feature counts as infinite)."""
    a, valid, _ = lin
    r = z8 - two_view_pixels(R_c[None], r_c[None], a, rig)[0]
    cost = np.where(valid, np.einsum("mk,mk->m", r, r) / sigma_px**2, np.inf)
    return float(np.median(cost)) if cost.size else np.inf


def _fit(
    a0: F64, z8: F64, motion: Motion, rig: RectifiedStereo, sigma_px: float
) -> tuple[Linearisation, float]:
    """The linearisation (``_linearised``) of the points ``a0`` over the pixels ``z8`` at the
    camera motion ``motion`` and its misfit (``_misfit``)."""
    lin = _linearised(a0, z8, *motion, rig)
    return lin, _misfit(lin, z8, *motion, rig, sigma_px)


def _better(lin: Linearisation, own: float, other: tuple[Linearisation, float]) -> Linearisation:
    """The linearisation (points, valid, null spaces) ``lin``, whose misfit is ``own``
    (``_misfit``), or ``other`` (another motion's, ``_fit``) if that fits the pixels better.
    The callers ask only once ``own`` exceeds ``WIDE_MISFIT``."""
    return other[0] if other[1] < own else lin


def _projected(N: F64, Y8: F64, z8: F64) -> F64:
    """Predicted minus tracked pixels (S, M, 8) onto the bases ``N`` (M, 8, 5): (S, 5M)."""
    # A batched matmul over the features, (M, S, 8) @ (M, 8, 5): 5x faster than the same
    # contraction by ``einsum`` (which does not reach BLAS here) at 49 sigma points x 300.
    return np.swapaxes(np.swapaxes(Y8 - z8, 0, 1) @ N, 0, 1).reshape(Y8.shape[0], -1)
