"""The camera-IMU rotation of the calibration, checked against the data while the run goes.

Between two frames the left camera turns by ``R_Ckm1_Ck = R_C_B ΔR_Bkm1_Bk R_B_C`` for a rigid
mount, so the rotation vectors obey ``Log R_Ckm1_Ck = R_C_B Log ΔR_Bkm1_Bk`` (``-Log R_Ck_Ckm1``
from the front end's egomotion; ``ΔR`` from the gyro, the filter's bias removed). A calibration
whose ``T_BS`` is inverted (camera-to-body given as body-to-camera), or has axes swapped, maps
the gyro's rotation axis away from the camera's. Each frame that turns by at least
``min_rotation_deg`` and ``min_snr`` times the two rotations' noise (the gyro's white noise
over the interval, the egomotion's rotation covariance: the axis of a turn near the noise
points anywhere; the paper's gyro, 7°/s per sample, gave a 30° median on a right mount with
1° alone) gives the angle between the two axes; after ``min_frames`` such frames,
a median above ``max_median_deg`` is warned once, naming the angle. Only the axis is compared:
a car turns about one axis, which fixes no full rotation, but a wrong mount still moves that
axis. Small errors (KITTI raw's 0.4°) are for ``vision.estimate_extrinsics``, not this test.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import StereoTracks
from svains.geometry.rotation import so3_log
from svains.models.state import BG
from svains.models.vision_imu import imu_increment
from svains.navigation.base import FrameContext
from svains.navigation.imu_history import ImuHistory
from svains.navigation.ins import default_imu_calib
from svains.sensors.types import ImuCalib

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class RotationCheckOptions:
    """Frames turning at least ``min_rotation_deg`` (gyro) count; after ``min_frames`` of them a
    median axis angle above ``max_median_deg`` is warned. A right mount gives a few degrees (the
    axis of a small turn is noisy: KITTI raw's median 1.3°, the simulator's 0.6°)."""

    min_rotation_deg: float = 1.0
    min_snr: float = 10.0
    min_frames: int = 10
    max_median_deg: float = 20.0


class RotationCheck:
    """Collects, frame by frame, the angle between the camera's and the gyro's rotation axes."""

    def __init__(self, history: ImuHistory, R_B_C: F64, gyro_noise_density: float,
                 options: RotationCheckOptions | None = None) -> None:  # fmt: skip
        """``history``: the body-frame IMU samples; ``R_B_C`` (3, 3): the (rectified) left
        camera's rotation on the body, as the calibration gives it; ``gyro_noise_density``
        rad/s/√Hz."""
        self.history = history
        self.R_C_B = np.asarray(R_B_C, dtype=float).T
        self.gyro_density = float(gyro_noise_density)
        self.options = options or RotationCheckOptions()
        self.angles_deg: list[float] = []
        self.warned = False

    def observe_frame(self, tr: StereoTracks | None, ctx: FrameContext) -> None:
        """``observe`` with the filter's gyro bias at the frame (none for the paper state)."""
        self.observe(tr, np.asarray(ctx.ukf.x[BG]) if ctx.layout.biased else None)

    def observe(self, tr: StereoTracks | None, bg_B: F64 | None) -> None:
        """The frame ``tr`` (its egomotion over ``[t_prev_ns, t_ns]``), the gyro bias ``bg_B``
        (3,) rad/s to remove (None: none)."""
        if tr is None or tr.egomotion is None or tr.t_ns <= tr.t_prev_ns:
            return
        h = self.history
        t = h.t_ns
        if t.size < 2 or t[0] > tr.t_prev_ns or t[-1] < tr.t_ns:
            return  # the samples of this interval are gone (or not there yet)
        inc = imu_increment(t, h.gyro_B, h.accel_B, tr.t_prev_ns, tr.t_ns, np.zeros(3), bg_B)
        r_B = so3_log(inc.dR_Bkm1_Bk)
        # noise of either rotation (rad): the gyro's white noise over the interval, and the
        # egomotion's rotation standard deviation
        var = self.gyro_density**2 * (tr.t_ns - tr.t_prev_ns) * 1e-9 * 3
        var += float(np.trace(np.asarray(tr.egomotion.cov, dtype=float)[:3, :3]))
        turn = float(np.linalg.norm(r_B))
        if (np.degrees(turn) < self.options.min_rotation_deg
                or not turn >= self.options.min_snr * np.sqrt(var)):  # fmt: skip
            return
        r_C = -so3_log(np.asarray(tr.egomotion.R_Ck_Ckm1, dtype=float))
        n_C = np.linalg.norm(r_C)
        if n_C == 0.0:
            return
        cos = float(r_C @ (self.R_C_B @ r_B)) / (n_C * float(np.linalg.norm(r_B)))
        self.angles_deg.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
        o = self.options
        if not self.warned and len(self.angles_deg) >= o.min_frames:
            median = float(np.median(self.angles_deg))
            if median > o.max_median_deg:
                self.warned = True
                log.warning(
                    "the camera turns about an axis %.0f° from the gyro's mapped through cam0's "
                    "T_BS (median of %d turning frames): is T_BS camera-to-body (not its "
                    "inverse), with the axes of the camera (x right, y down, z forward)?",
                    median, len(self.angles_deg),
                )

    def summary(self) -> dict[str, object]:
        """``frames`` compared and the ``median_axis_deg`` (None before any)."""
        a = self.angles_deg
        return {"frames": len(a), "median_axis_deg": float(np.median(a)) if a else None,
                "warned": self.warned}  # fmt: skip


def rotation_check(history: ImuHistory | None, R_B_C: F64,
                   imu: ImuCalib | None) -> RotationCheck | None:  # fmt: skip
    """A check of ``R_B_C`` on ``history``'s gyro (noise from ``imu``, else the filter's
    default), or None without an IMU."""
    if history is None:
        return None
    return RotationCheck(history, R_B_C, (imu or default_imu_calib()).gyro_noise_density)
