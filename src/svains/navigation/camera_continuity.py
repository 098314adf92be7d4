"""Who moved, the camera or the filter: a vision frame refused right after a fused one.

GPS-denied, a vision update refused with a NIS far beyond its gate right after a fused frame
is tested for a jump of the camera (``consistency``: a frozen or stuck view, a replayed frame),
and a jumped camera is distrusted until it agrees again, unless an IMU fault came between.
An IMU fault the IMU checks miss (a burst of plausible values: a user's probe, gyro and
accelerometer 20-50x for 0.5 s on KITTI raw) corrupts the state the same way, and the
camera was then distrusted for the rest of the run: 926 m off instead of 4 m.

The frame's own motion tells them apart. Per second, the camera motion the last fused frame
agreed on (the filter's prediction after that update), the motion the refused frame measures
(its egomotion) and the motion the filter predicts for it: a stuck or replayed camera measures
a motion unlike the one before while the filter's prediction carries on; after a missed IMU
fault the camera's motion carries on and the prediction left it. A camera that measures no
motion is never taken to carry one on (a stuck view at a hover's end). Only over short frames
(``MAX_GAP_S``, where the motion cannot change much) and soon after the fused frame
(``MAX_SINCE_FUSED_S``); elsewhere nothing is concluded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_log
from svains.models.vision_clone import predict_egomotion_clone
from svains.navigation.base import FrameContext
from svains.navigation.vision_clones import CloneWindow

F64 = NDArray[np.float64]

# The filter left the camera's motion when its prediction moved this many times farther from
# the agreed motion than the camera's measurement did (each block: rotation, translation).
RATIO = 3.0
# Frames at most this long (s): over longer ones the motion itself may change.
MAX_GAP_S = 1.0
# ...and refused at most this long (s) after the last fused frame.
MAX_SINCE_FUSED_S = 1.5
_BLOCKS = (slice(0, 3), slice(3, 6))  # of a motion (6,): rotation, translation


def predicted_motion(
    ctx: FrameContext, clones: CloneWindow | None, rig: RectifiedStereo, tr: StereoTracks | None
) -> F64 | None:
    """The camera motion ``(Log R_Ck_Ckm1, p_Ck_Ckm1)`` per second (6,) [rad/s, m/s] the
    filter's mean predicts between the clone of ``tr``'s k-1 frame and now; None without
    one."""
    if clones is None or tr is None or tr.t_ns <= tr.t_prev_ns:
        return None
    cols = clones.columns(ctx.ukf, tr.t_prev_ns)
    if cols is None:
        return None
    out = predict_egomotion_clone(ctx.ukf.x, cols, rig, clones.calib(ctx.ukf),
                                  clones.td(ctx.ukf, ctx.t_ns))  # fmt: skip
    return np.asarray(out, float) / ((tr.t_ns - tr.t_prev_ns) * 1e-9)


def measured_motion(ego: Egomotion, dt_s: float) -> tuple[F64, F64]:
    """The egomotion per second (6,) and its standard deviation per block (rotation,
    translation) per second."""
    z = np.concatenate([so3_log(ego.R_Ck_Ckm1), ego.p_Ck_Ckm1]) / dt_s
    std = np.sqrt([np.trace(ego.cov[b, b]) for b in _BLOCKS]) / dt_s
    return z, std


@dataclass
class CameraContinuity:
    """The camera motion per second the last fused frame agreed on, and its time (ns)."""

    agreed: F64 | None = None
    agreed_ns: int | None = None

    def fused(self, t_ns: int, predicted: F64 | None) -> None:
        """A fused frame at ``t_ns``; ``predicted``: the motion the filter predicts after it."""
        self.agreed, self.agreed_ns = predicted, int(t_ns)

    def may_judge(self, t_ns: int, dt_s: float) -> bool:
        """Whether a frame refused at ``t_ns``, ``dt_s`` after the one before, can be judged."""
        return (self.agreed is not None and self.agreed_ns is not None and dt_s <= MAX_GAP_S
                and (t_ns - self.agreed_ns) * 1e-9 <= MAX_SINCE_FUSED_S)  # fmt: skip

    def filter_moved(self, measured: F64, measured_std: F64, predicted: F64) -> bool:
        """Whether the refused frame's measured motion carries on the agreed one while the
        filter's prediction left it (see the module): the camera measures a motion, in some
        block the prediction moved more than ``RATIO`` times as far as the measurement (and
        beyond its noise), and in none did the measurement move farther than the prediction."""
        assert self.agreed is not None
        # A camera that measures no motion carries nothing on: a stuck view while the vehicle
        # sets off would look continuous with a hover (a reviewer's case).
        if not any(np.linalg.norm(measured[b]) > 3.0 * std
                   for b, std in zip(_BLOCKS, measured_std, strict=True)):
            return False
        left = False
        for block, std in zip(_BLOCKS, measured_std, strict=True):
            d_cam = float(np.linalg.norm(measured[block] - self.agreed[block]))
            d_filter = float(np.linalg.norm(predicted[block] - self.agreed[block]))
            if d_cam > d_filter + 3.0 * std:
                return False
            left |= d_filter > RATIO * d_cam + 3.0 * std
        return left
