"""IMU side of the vision updates: increments between frames and the front end's motion prior.

- ``ImuIncrements``: the IMU samples integrated between two frame times (``rotation="imu"``
  models, ``models.vision_imu``), with the filter's mean biases removed.
- ``MotionPrior``: the camera motion ``T_Ck_Ckm1`` the filter predicts between the front end's
  reference frame and the new frame, with a covariance, handed to the image front end
  (``ImageFrames.tracks_at``): it starts KLT where features should land, competes in
  RANSAC, and rejects estimates that contradict it (e.g. a moving object filling the view).
- ``CachedModel``: ``h`` of the kept features that reuses the gate pass's predictions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_log
from svains.models.state import BA, BG
from svains.models.vision_common import ImuIncrement, camera_motion
from svains.models.vision_imu import imu_increment
from svains.navigation.base import FrameContext
from svains.navigation.imu_history import ImuHistory
from svains.sensors.types import ImuCalib

F64 = NDArray[np.float64]


class ImuIncrements:
    """IMU samples (body frame) for the increments between two frame times."""

    def __init__(
        self, history: ImuHistory, g_W: F64, cal: ImuCalib | None, imu_noise: bool = True
    ) -> None:
        self.history = history
        self.g_W = np.asarray(g_W, float)
        # White-noise densities (gyro rad/s/√Hz, accel m/s²/√Hz); None without a calibration.
        self.densities: tuple[float, float] | None = (
            None if cal is None else (cal.gyro_noise_density, cal.accel_noise_density)
        )
        # ... as pixel noise of the ``imu`` models only when asked (``VisionOptions.imu_noise``).
        self.noise = self.densities if imu_noise else None

    def between(self, ctx: FrameContext, t0_ns: int, t1_ns: int) -> ImuIncrement:
        """Increment over [t0, t1] with the filter's mean biases removed."""
        x = ctx.ukf.x
        biased = ctx.layout.biased
        h = self.history
        return imu_increment(
            h.t_ns, h.gyro_B, h.accel_B, t0_ns, t1_ns, self.g_W,
            x[BG] if biased else None, x[BA] if biased else None,
        )


@dataclass(frozen=True)
class MotionPriorOptions:
    """How generous the prior is: the sigma-point covariance plus the IMU white noise over Δt is
    multiplied by ``inflation`` (variance), then each standard deviation is floored at
    ``min_std`` (rad for the rotation, m for the translation) and at ``rel_std`` times the
    predicted rotation angle / translation length. A too-tight prior makes the front end reject
    good frames (``contradicts_prior``), and the front end's own covariance, the other term of
    its gate, is optimistic. Defaults measured on the simulated village (20 Hz and 2 Hz): NEES
    of the true motion about 1 for 6 degrees of freedom, i.e. ~6x generous in variance.
    ``after_s``: the prior is handed over only for frames at least this long (s) after the
    front end's reference frame (None: for every frame)."""

    inflation: float = 4.0
    min_std: tuple[float, float] = (2e-3, 5e-3)
    rel_std: float = 0.05
    after_s: float | None = None


def imu_motion_prior(
    X: F64, Wm: F64, Wc: F64, x_mean: F64, dt_s: float, rig: RectifiedStereo,
    inc: ImuIncrement, densities: tuple[float, float] | None,
    options: MotionPriorOptions = MotionPriorOptions(),
) -> Egomotion:
    """``T_Ck_Ckm1`` (``p_Ck = R p_Ckm1 + p``) predicted from the state at t_k and the IMU
    increment ``inc`` over the ``dt_s`` before it, with its covariance (6, 6) over (local
    rotation vector, translation), see ``MotionPriorOptions``.

    ``X`` (S, nx) sigma points at t_k with weights ``Wm``/``Wc`` (S,), ``x_mean`` (nx,) the mean:
    the motion is ``camera_motion(..., "imu")`` (``d_k = R_c d - r_c``, so ``R = R_c``,
    ``p = -r_c``) and its spread over the sigma points is the state's share (velocity, attitude
    and bias uncertainty); the IMU white noise adds ``σ_g² Δt`` and ``σ_a² Δt³/3`` per axis.
    """
    R_c, r_c = camera_motion(np.vstack([x_mean[None, :], X]), dt_s, rig, "imu", inc)
    R0, p0 = R_c[0], -r_c[0]
    dev = np.concatenate([so3_log(R0.T @ R_c[1:]), -r_c[1:] - p0], axis=1)  # (S, 6)
    dev -= Wm @ dev
    cov = dev.T @ (Wc[:, None] * dev)
    if densities is not None:
        cov[:3, :3] += densities[0] ** 2 * dt_s * np.eye(3)
        cov[3:, 3:] += densities[1] ** 2 * dt_s**3 / 3.0 * np.eye(3)
    cov = options.inflation * 0.5 * (cov + cov.T)
    scale = np.repeat([np.linalg.norm(so3_log(R0)), np.linalg.norm(p0)], 3)
    floor = np.maximum(np.repeat(options.min_std, 3), options.rel_std * scale) ** 2
    cov += np.diag(np.maximum(floor - np.diag(cov), 0.0))
    return Egomotion(R_Ck_Ckm1=R0, p_Ck_Ckm1=p0, cov=cov)


class MotionPrior:
    """Per-frame ``imu_motion_prior`` for an image source over [its reference frame, t_k]."""

    def __init__(
        self, increments: ImuIncrements, rig: RectifiedStereo, options: MotionPriorOptions
    ) -> None:
        self.increments = increments
        self.rig = rig
        self.options = options

    def wanted(self, t_ns: int, t_ref_ns: int | None) -> bool:
        """Whether the frame at ``t_ns`` gets the prior (``MotionPriorOptions.after_s``)."""
        after_s = self.options.after_s
        return after_s is None or (t_ref_ns is not None and (t_ns - t_ref_ns) * 1e-9 >= after_s)

    def for_frame(
        self, ctx: FrameContext, t_ref_ns: int | None
    ) -> tuple[Egomotion | None, ImuIncrement | None]:
        """The prior for the tracks ``t_ref_ns`` -> ``ctx.t_ns`` (the filter is at ``ctx.t_ns``)
        and the IMU increment it used (None, None without a usable reference)."""
        if t_ref_ns is None or t_ref_ns >= ctx.t_ns or t_ref_ns < self.increments.history.t_ns[0]:
            return None, None
        inc = self.increments.between(ctx, t_ref_ns, ctx.t_ns)
        X, _ = ctx.ukf.sigma_points()
        pts = ctx.ukf.points
        prior = imu_motion_prior(
            X, pts.Wm, pts.Wc, ctx.ukf.x, (ctx.t_ns - t_ref_ns) * 1e-9, self.rig, inc,
            self.increments.densities, self.options,
        )
        return prior, inc


class CachedModel:
    """``h`` restricted to kept features, reusing the gate pass's predictions ``Y0`` for the
    same sigma points ``X0`` (the UKF reuses its draw while the state is unchanged)."""

    def __init__(self, h_sub: Any, X0: F64, Y0: F64) -> None:
        self._h = h_sub
        self._X0 = X0
        self._Y0 = Y0

    def __call__(self, X: F64) -> F64:
        if X is self._X0 or (X.shape == self._X0.shape and np.array_equal(X, self._X0)):
            return self._Y0
        return self._h(X)
