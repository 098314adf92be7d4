"""The frame's egomotion as one 6-number measurement (``lc``), and the ``tc``/``3d`` fallback to it.

``lc`` fuses every frame this way. ``tc``/``3d`` fuse the pixels, whose sigma-point predictions
need a prior narrow against the scene's depth: with frames seconds apart on a flying vehicle the
IMU-only prior is metres wide and its sigma points put the features behind the camera, so no
feature is valid and the filter would stay on the IMU for good (issue 22: EuRoC, frames 5 s
apart). Such a frame fuses its egomotion instead (the pixels enter once, through it), gated like
any other sensor; the next frame then meets a prior the pixels can be linearised over.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.models.vision_lc import egomotion_measurement
from svains.navigation.base import MeasurementBlock
from svains.navigation.options import VisionOptions

F64 = NDArray[np.float64]


def egomotion_noise(ego: Egomotion, options: VisionOptions) -> tuple[F64, F64] | None:
    """``z`` (6,) rad, m and its covariance (6, 6): the front end's covariance times
    ``options.lc_scale(ego.estimator)``, standard deviations floored at ``lc_min_std``; None
    when the covariance is not finite and positive definite (a poorly conditioned egomotion
    from a few features can give an indefinite one: no weight can be given to that motion)."""
    z, cov = egomotion_measurement(ego)
    cov = cov * options.lc_scale(ego.estimator)
    floor = np.repeat(np.square(options.lc_min_std), 3)
    cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
    if not (np.isfinite(cov).all() and np.linalg.eigvalsh(cov)[0] > 0):
        return None
    return z, cov


def tracks_egomotion(
    tr: StereoTracks, rig: RectifiedStereo, seed: int, bundle: bool = False,
    covariance: bool = True,
) -> Egomotion | None:
    """The egomotion the tracks carry, or that of their inliers (the front end's RANSAC +
    refinement, at wider inlier thresholds while that finds none:
    ``frontend.egomotion.estimate_egomotion_widening``), with ``bundle``
    refined by the two-frame bundle adjustment (``frontend.egomotion_bundle.refine_or_keep``).
    ``covariance`` False: for the motion only, RANSAC's covariance is not computed (NaN; the
    motion is the same)."""
    if tr.egomotion is not None:
        return tr.egomotion
    ok = tr.inlier & np.isfinite(tr.p_Ckm1_F).all(axis=1)
    if ok.sum() < 3:
        return None
    # Imported here: only frames that fall back need the front end's estimator.
    from svains.frontend.egomotion import RansacOptions, estimate_egomotion_widening

    uvl, uvr = tr.uv_left[ok], tr.uv_right[ok]
    res = estimate_egomotion_widening(tr.p_Ckm1_F[ok], uvl, uvr, rig, RansacOptions(seed=seed),
                                      p_cur=rig.triangulate(uvl, uvr),
                                      covariance=covariance)  # fmt: skip
    if res.egomotion is None or not bundle:
        return res.egomotion
    from svains.frontend.egomotion_bundle import refine_or_keep

    return refine_or_keep(res.egomotion, res.inlier, tr.uv_left_prev[ok], tr.uv_right_prev[ok],
                          uvl, uvr, rig)[0]  # fmt: skip


def egomotion_block(
    name: str, ego: Egomotion, options: VisionOptions, h: Callable[[F64], F64]
) -> MeasurementBlock | None:
    """The egomotion ``ego`` as a measurement block with model ``h`` ((S, nx) -> (S, 6)); None
    when its covariance is unusable (``egomotion_noise``)."""
    zc = egomotion_noise(ego, options)
    return None if zc is None else MeasurementBlock(name=name, h=h, z=zc[0], R=zc[1])
