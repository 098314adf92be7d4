"""The camera-IMU rotation of the calibration, checked against the data while the run goes.

Between two frames the left camera turns by ``R_Ckm1_Ck = R_C_B ΔR_Bkm1_Bk R_B_C`` for a rigid
mount, so the rotation vectors obey ``Log R_Ckm1_Ck = R_C_B Log ΔR_Bkm1_Bk`` (``-Log R_Ck_Ckm1``
from the front end's egomotion; ``Log ΔR`` taken as the gyro's rates integrated over the
interval, the filter's bias removed: equal to first order, and not wrapped past π). A calibration
whose ``T_BS`` is inverted (camera-to-body given as body-to-camera), or has axes swapped, maps
the gyro's rotation axis away from the camera's. Each frame that turns by at least
``min_rotation_deg`` and ``min_snr`` times the two rotations' noise (the gyro's white noise
over the interval, the egomotion's rotation covariance: the axis of a turn near the noise
points anywhere; the paper's gyro, 7°/s per sample, gave a 30° median on a right mount with
1° alone) gives the angle between the two axes; after ``min_frames`` such frames,
a median above ``max_median_deg`` is warned once, naming the angle. Only the axis is compared:
a car turns about one axis, which fixes no full rotation, but a wrong mount still moves that
axis. Small errors (KITTI raw's 0.4°) are for ``vision.estimate_extrinsics``, not this test.
The same frames compare the two turns' sizes: a median gyro turn outside 0.5-2 times the
camera's is warned too (a gyro in deg/s turns 57 times as far), with or without GPS.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import StereoTracks
from svains.geometry.rotation import so3_log
from svains.models.state import BG
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
    # the gyro's turn over the camera's: a median outside this band is warned (deg/s: 57)
    turn_ratio_band: tuple[float, float] = (0.5, 2.0)


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
        self.ratios: list[float] = []  # |gyro turn| / |camera turn| per counted frame
        self.warned = False
        self.warned_ratio = False

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
        r_B = _gyro_turn(t, h.gyro_B, tr.t_prev_ns, tr.t_ns, bg_B)
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
        self.ratios.append(turn / n_C)
        o = self.options
        lo, hi = o.turn_ratio_band
        if not self.warned_ratio and len(self.ratios) >= o.min_frames:
            ratio = float(np.median(self.ratios))
            if not lo <= ratio <= hi:
                self.warned_ratio = True
                hint = " (one in deg/s turns 57 times as far)" if ratio > 10 else ""
                log.warning("the gyro turns %.3g times as far as the camera (median of %d "
                            "turning frames): is the gyro in rad/s%s?", ratio, len(self.ratios),
                            hint)  # fmt: skip
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
        """``frames`` compared, the ``median_axis_deg`` and ``median_turn_ratio`` (gyro over
        camera; None before any), and whether each was warned."""
        a, r = self.angles_deg, self.ratios
        return {"frames": len(a), "median_axis_deg": float(np.median(a)) if a else None,
                "median_turn_ratio": float(np.median(r)) if r else None,
                "warned": self.warned, "warned_turn_ratio": self.warned_ratio}  # fmt: skip


def _gyro_turn(t_ns: NDArray[np.int64], gyro_B: F64, t0_ns: int, t1_ns: int,
               bg_B: F64 | None) -> F64:
    """The gyro's rates (bias ``bg_B`` removed) integrated over ``[t0_ns, t1_ns]`` (3,) rad,
    trapezoids with the ends interpolated: the rotation vector of the turn to first order, and
    unlike the log of the composed rotation, not wrapped past π (a gyro read in deg/s turns
    by radians between two frames)."""
    i0 = max(int(np.searchsorted(t_ns, t0_ns, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(t_ns, t1_ns, side="left")) + 1, t_ns.size)
    t = (t_ns[i0:i1] - t0_ns) * 1e-9
    w = gyro_B[i0:i1] - (0.0 if bg_B is None else bg_B)
    cum = np.vstack([np.zeros(3), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t)[:, None], axis=0)])
    end = (t1_ns - t0_ns) * 1e-9
    return np.array([np.interp(end, t, cum[:, k]) - np.interp(0.0, t, cum[:, k])
                     for k in range(3)])  # fmt: skip


def rotation_check(history: ImuHistory | None, R_B_C: F64,
                   imu: ImuCalib | None) -> RotationCheck | None:  # fmt: skip
    """A check of ``R_B_C`` on ``history``'s gyro (noise from ``imu``, else the filter's
    default), or None without an IMU."""
    if history is None:
        return None
    return RotationCheck(history, R_B_C, (imu or default_imu_calib()).gyro_noise_density)
