"""The camera-IMU rotation of the calibration, checked against the data while the run goes.

Between two frames the left camera turns by ``R_Ckm1_Ck = R_C_B ΔR_Bkm1_Bk R_B_C`` for a rigid
mount, so the rotation vectors obey ``Log R_Ckm1_Ck = R_C_B Log ΔR_Bkm1_Bk`` (``-Log R_Ck_Ckm1``
from the front end's egomotion; ``Log ΔR`` taken as the gyro's rates integrated over the
interval with the second-order coning term, the filter's bias removed, not wrapped past π).
A calibration whose ``T_BS`` is inverted (camera-to-body given as body-to-camera), or has axes
swapped, maps the gyro's rotation axis away from the camera's. Each frame that turns by at least
``min_rotation_deg`` and ``min_snr`` times the two rotations' noise (the gyro's white noise
over the interval, the egomotion's rotation covariance: the axis of a turn near the noise
points anywhere; the paper's gyro, 7°/s per sample, gave a 30° median on a right mount with
1° alone) gives the angle between the two axes; after ``min_frames`` such frames,
a median above ``max_median_deg`` is warned once, naming the angle. Only the axis is compared:
a car turns about one axis, which fixes no full rotation, but a wrong mount still moves that
axis. Small errors (KITTI raw's 0.4°) are for ``vision.estimate_extrinsics``, not this test.
The same frames compare the two turns' sizes: a median gyro turn outside 0.5-2 times the
camera's is warned too (a gyro in deg/s turns 57 times as far), with or without GPS.
The same frames test the camera stamps against the IMU's clock: the gyro's turn over each
frame's interval shifted by up to ``offset_range_s`` either way, against the camera's; a best
shift of ``offset_warn_s`` or more, beyond 4 of its standard deviations and explaining the
turns (``offset_max_fit``), is warned once with the ``timeshift_cam_imu`` to give.
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
from svains.navigation.imu_history import ImuHistory, shifted_integrals
from svains.navigation.ins import default_imu_calib
from svains.sensors.types import ImuCalib

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
# a turning frame: t0_ns, t1_ns, the camera's turn (3,) rad in body axes, gyro bias or None,
# the turns' noise variance
_Frame = tuple[int, int, F64, "F64 | None", float]


@dataclass(frozen=True)
class RotationCheckOptions:
    """Frames turning at least ``min_rotation_deg`` (gyro) count; after ``min_frames`` of them a
    median axis angle above ``max_median_deg`` is warned. A right mount gives a few degrees (the
    axis of a small turn is noisy: KITTI raw's median 1.3°, the simulator's 0.6°)."""

    min_rotation_deg: float = 1.0
    min_snr: float = 10.0
    # frames further apart are left out: the integrated rate equals the turn's rotation vector
    # to second order only (a user's probe, at first order: EuRoC frames 7 s apart, exact
    # features, gave a turn scale of 0.967 and a 51 ms offset, both warned; up to 3 s apart,
    # 1.000 and under 2 ms)
    max_interval_s: float = 1.0
    min_frames: int = 10
    max_median_deg: float = 20.0
    # the gyro's turn over the camera's: a median outside this band is warned (deg/s: 57)
    turn_ratio_band: tuple[float, float] = (0.5, 2.0)
    # camera stamps against the IMU's: shifts tried (s, each way) and their step, and the
    # smallest best shift warned (and only beyond 4 of its standard deviations)
    offset_range_s: float = 0.3
    offset_step_s: float = 0.0025
    # beyond that range, shifts out to this far (s, each way) on a coarser step: stamps a second
    # or more off (KITTI raw's camera 1 s late: ATE 0.28 -> 1.42 m, and no word but IMU bias
    # alarms), warned when such a shift halves the best misfit of the near ones
    offset_far_s: float = 3.0
    offset_far_step_s: float = 0.025
    # (since a user's probe: a 5 ms offset, measured to ±0.07 ms, went unsaid at 15 ms and
    # made the run 3-6x worse; KITTI raw reads -0.8 ± 3.6 ms)
    offset_warn_s: float = 0.003
    # ... and only when that shift explains the turns (misfit per degree of freedom at most
    # this: KITTI raw 0.99, 1.6 with its stamps 50 ms off, 13.4 at 150 ms, where the filter's
    # gyro bias, fed the late frames, is off too; a mount 20° off gives hundreds)
    offset_max_fit: float = 30.0
    # the camera's turn per gyro turn (best common factor at the best shift) warned when this
    # far from 1 and beyond 4 of its standard deviations (a focal length 10 % off: 0.91/1.10;
    # a MAV's turns about the optical axis carry no focal length: 5 % off read 0.977 ± 0.0006,
    # unsaid at 0.03, the run 13x worse, a user's probe; KITTI raw reads 1.007 ± 0.005, the
    # tests' synthetic gyro, held between samples, 1.016 ± 0.002)
    scale_warn: float = 0.02
    # ... and, where the turns fit poorly (beyond ``offset_max_fit``), from this far
    poor_fit_scale_warn: float = 0.1
    # the camera's rotation on the body that best maps its turns onto the gyro's (all frames,
    # least squares) warned when at least this far from the calibration's and beyond 4 of its
    # standard deviations (3-5° off went unsaid under the 20° median test, the run 9-40x
    # worse, fixed by ``vision.estimate_extrinsics``: a user's probe)
    mount_warn_deg: float = 1.0


class RotationCheck:
    """Collects, frame by frame, the angle between the camera's and the gyro's rotation axes."""

    def __init__(self, history: ImuHistory, R_B_C: F64, gyro_noise_density: float,
                 options: RotationCheckOptions | None = None,
                 applied_shift_s: float = 0.0) -> None:  # fmt: skip
        """``history``: the body-frame IMU samples; ``R_B_C`` (3, 3): the (rectified) left
        camera's rotation on the body, as the calibration gives it; ``gyro_noise_density``
        rad/s/√Hz; ``applied_shift_s``: the calibration's ``timeshift_cam_imu`` (s) already
        applied to the stamps the check sees, to which a shift it finds adds."""
        self.history = history
        self.applied_shift_s = float(applied_shift_s)
        self.R_C_B = np.asarray(R_B_C, dtype=float).T
        self.gyro_density = float(gyro_noise_density)
        self.options = options or RotationCheckOptions()
        self.angles_deg: list[float] = []
        self.ratios: list[float] = []  # |gyro turn| / |camera turn| per counted frame
        self.warned = False
        self.warned_ratio = False
        o = self.options
        n = round(o.offset_range_s / o.offset_step_s)
        self._near = _ShiftSums(np.arange(-n, n + 1) * o.offset_step_s)
        # per shift, over the counted frames (each term over the frame's noise): the gyro's
        # turn squared, its product with the camera's, and the camera's turn squared
        self.warned_offset = False
        # the same sums over the far shifts (``offset_far_s``), beyond the near ones
        m = round(o.offset_far_s / o.offset_far_step_s)
        far = np.arange(-m, m + 1) * o.offset_far_step_s
        self._far = _ShiftSums(far[np.abs(far) > o.offset_range_s])
        self.warned_scale = False
        self.warned_mount = False
        self.warned_lens = False  # the turn scale told with turns that fit poorly
        # the turning frames at which the offset and the turn scale first called for a
        # warning, since when they have at every frame (``_held``)
        self._flagged_at: dict[str, int] = {}
        self._at_end = False  # judging at the run's end (``summary``)
        # Σ g cᵀ / var and Σ |g|² / var over the counted frames: the gyro's turn g and the
        # camera's c in body axes through the calibration (the mount's least squares)
        self._H = np.zeros((3, 3))
        # Σ (|g|² I - g gᵀ) / var: the information on a small rotation δ of the mount (a turn
        # g is moved by δ × g): none about the axis every turn shares
        self._info = np.zeros((3, 3))
        self._gg = 0.0
        self._cc = 0.0
        self._mount_frames = 0

    @property
    def offset_frames(self) -> int:
        """Turning frames in the near shifts' sums."""
        return self._near.frames

    @property
    def far_frames(self) -> int:
        """Turning frames in the far shifts' sums."""
        return self._far.frames

    @property
    def _offset_pending(self) -> list[_Frame]:
        return self._near.pending

    def observe_frame(self, tr: StereoTracks | None, ctx: FrameContext) -> None:
        """``observe`` with the filter's gyro bias at the frame (none for the paper state)."""
        self.observe(tr, np.asarray(ctx.ukf.x[BG]) if ctx.layout.biased else None)

    def observe(self, tr: StereoTracks | None, bg_B: F64 | None) -> None:
        """The frame ``tr`` (its egomotion over ``[t_prev_ns, t_ns]``), the gyro bias ``bg_B``
        (3,) rad/s to remove (None: none)."""
        self._flush_offsets()
        if tr is None or tr.egomotion is None or tr.t_ns <= tr.t_prev_ns:
            return
        if (tr.t_ns - tr.t_prev_ns) * 1e-9 > self.options.max_interval_s:
            return
        h = self.history
        t = h.t_ns
        if t.size < 2 or t[0] > tr.t_prev_ns or t[-1] < tr.t_ns:
            return  # the samples of this interval are gone (or not there yet)
        if h.fault_in(tr.t_prev_ns, tr.t_ns):
            return  # samples dropped or missing: the gyro's turn is a bridge's
        r_B = _gyro_turns(t, h.gyro_B, tr.t_prev_ns, tr.t_ns, bg_B, _NO_SHIFT)[0]
        # noise of either rotation (rad): the gyro's white noise over the interval, and the
        # egomotion's rotation standard deviation
        var = self.gyro_density**2 * (tr.t_ns - tr.t_prev_ns) * 1e-9 * 3
        var += float(np.trace(np.asarray(tr.egomotion.cov, dtype=float)[:3, :3]))
        if not var >= 0.0:
            return  # a degenerate egomotion covariance (negative or NaN trace): nothing to test
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
        c_B = self.R_C_B.T @ r_C
        self._H += np.outer(r_B, c_B) / var
        self._info += (float(r_B @ r_B) * np.eye(3) - np.outer(r_B, r_B)) / var
        self._gg += float(r_B @ r_B) / var
        self._cc += float(c_B @ c_B) / var
        self._mount_frames += 1
        self._observe_offset(tr.t_prev_ns, tr.t_ns, c_B, bg_B, var)
        self._observe_far(tr.t_prev_ns, tr.t_ns, c_B, bg_B, var)
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
        self._judge_axes()

    def _judge_axes(self) -> None:
        """Warn once when the turns' median axis angle says the mount is wrong; then the
        mount's least squares (``_judge_mount``)."""
        o = self.options
        # Camera stamps off the IMU's clock move the turns' axes too: that is told first (the
        # stamps' test counts only frames whose shifted intervals the history holds, and an
        # offset called for waits to hold: ``_held``).
        judged = ((self.offset_frames >= o.min_frames or len(self.angles_deg) >= 2 * o.min_frames)
                  and "offset" not in self._flagged_at)  # fmt: skip
        if (not self.warned and not self.warned_offset and not self.warned_ratio and judged
                and len(self.angles_deg) >= o.min_frames):  # fmt: skip
            median = float(np.median(self.angles_deg))
            if median > o.max_median_deg:
                self.warned = True
                log.warning(
                    "the camera turns about an axis %.0f° from the gyro's mapped through cam0's "
                    "T_BS (median of %d turning frames): is T_BS camera-to-body (not its "
                    "inverse), with the axes of the camera (x right, y down, z forward)? Or is "
                    "the IMU in other axes than imu0's T_BS says (the body's, often)?",
                    median, len(self.angles_deg),
                )
        if judged and len(self.angles_deg) >= o.min_frames:
            self._judge_mount()

    def mount_error(self) -> tuple[float, float, F64, float] | None:
        """The rotation (deg) of cam0 on the body that best maps the camera's turns onto the
        gyro's beyond the calibration's (``R_B_C,true = R @ R_B_C``), its standard deviation
        (deg; scaled by the misfit per degree of freedom when above 1), its axis (3,) in body
        axes and that misfit; None before ``min_frames`` turning frames."""
        if self._mount_frames < self.options.min_frames or self._gg <= 0.0:
            return None
        U, _, Vt = np.linalg.svd(self._H)
        D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
        R = U @ D @ Vt  # argmin Σ |R c - g|² / var
        r = so3_log(R)
        misfit = self._gg + self._cc - 2.0 * float(np.trace(R @ self._H.T))
        fit = misfit / max(3 * self._mount_frames - 3, 1)
        # Only the directions the turns inform: turns about one axis tell nothing of a mount
        # rotation about it, and its component is noise (a drone turning about body y read a
        # right mount 2-3.6° ± 0.2° off about y, warned: a user's probe).
        lam, V = np.linalg.eigh(self._info)
        seen = lam >= MOUNT_MIN_INFO * max(float(lam[-1]), 1e-300)
        r = V[:, seen] @ (V[:, seen].T @ r)
        angle = float(np.linalg.norm(r))
        axis = r / angle if angle > 0.0 else np.zeros(3)
        u = axis if angle > 0.0 else V[:, -1]
        var_u = float(np.sum((V[:, seen].T @ u) ** 2 / lam[seen]))
        std = float(np.sqrt(var_u * max(fit, 1.0)))
        return float(np.degrees(angle)), float(np.degrees(std)), axis, float(fit)

    def _judge_mount(self) -> None:
        """Warn once when the camera's rotation on the body is clearly off the calibration's
        by a degree or more (less than the axis test's 20°, more than its noise)."""
        o = self.options
        if self.warned_mount or self.warned or self.warned_offset or self.warned_ratio:
            return
        got = self.mount_error()
        if got is None:
            return
        angle, std, axis, fit = got
        if angle < o.mount_warn_deg or angle <= 4.0 * std:
            return
        if fit > o.offset_max_fit:
            return  # no rotation maps the turns (a lens model, stamps): not the mount's
        self.warned_mount = True
        log.warning(
            "the camera's turns fit the gyro's best with cam0 turned %.2f° ± %.2f° on the body "
            "from its T_BS (about body axis [%.2f, %.2f, %.2f], %d turning frames): a "
            "camera-IMU rotation that far off costs accuracy; set "
            "vision.estimate_extrinsics=true to estimate it, or recalibrate", angle, std,
            *axis, self._mount_frames,
        )  # fmt: skip

    def _observe_offset(self, t0_ns: int, t1_ns: int, r_B: F64, bg_B: F64 | None,
                        var: float) -> None:  # fmt: skip
        """Add the frame's misfit, for each tried shift ``δ``, between the camera's turn
        ``r_B`` (3,) rad (body axes) and the gyro's over ``[t0 + δ, t1 + δ]``, weighted by the
        frame's noise ``var``; warn once when the best shift is clearly not zero."""
        o = self.options
        if not self._near.add(self.history, (t0_ns, t1_ns, r_B, bg_B, var)):
            return
        if self.offset_frames < o.min_frames:
            return
        self._judge_scale()
        self._judge_offset()

    def _judge_offset(self) -> None:
        """Warn once when the best shift is clearly not zero (and has been so: ``_held``)."""
        o = self.options
        if self.warned_offset or self.warned:
            return  # told, or a mount told wrong (its turns' axes say nothing of the stamps)
        got = self.time_offset()
        if got is None:
            self._held("offset", False)  # a call not made at every frame is not held
            if not (self.far_frames < o.min_frames and self._far.pending):
                self._judge_edge()  # else the far shifts, judged a few seconds on, say how far
            return
        shift, std = got
        fit = self.offset_fit()
        # no shift explains the turns beyond the fit's limit: a mount error, told by the axes
        # (a call left standing through it held the axes back and was said at the end: a review)
        explains = fit is not None and fit <= o.offset_max_fit
        if self._held("offset", explains and abs(shift) >= o.offset_warn_s
                      and abs(shift) > 4.0 * std):  # fmt: skip
            self.warned_offset = True
            log.warning(
                "the camera's turns match the gyro's best with the IMU %.0f ms %s the camera "
                "stamps (± %.0f ms, %d turning frames): are the images stamped on the IMU's "
                "clock? Give timeshift_cam_imu: %+.3f (t_imu = t_cam + shift%s) in the camera "
                "calibration, or let the filter estimate it (vision.estimate_time_offset)",
                abs(shift) * 1e3, "after" if shift > 0 else "before", std * 1e3,
                self.offset_frames, self.applied_shift_s + shift, self._added(shift, 3),
            )

    def _judge_edge(self) -> None:
        """The best near shift at the edge of those tried (and none of the far ones judged):
        warned when it halves the misfit at zero (a mount error moves it little: 0.83 for 90°
        off, 0.99 for 20°)."""
        if self.warned_offset or self.warned or self.offset_frames < self.options.min_frames:
            return
        c = self._offset_chi2
        k = int(np.argmin(c))
        zero = c.size // 2
        if k in (0, c.size - 1) and c[zero] - c[k] > 25.0 and c[k] < 0.5 * c[zero]:
            self.warned_offset = True
            log.warning(
                "the camera's turns match the gyro's best with the IMU more than %.0f ms "
                "%s the camera stamps (%d turning frames): are the images stamped on the "
                "IMU's clock? Measure the offset and give it as timeshift_cam_imu in the "
                "camera calibration", self.options.offset_range_s * 1e3,
                "after" if k > zero else "before", self.offset_frames,
            )  # fmt: skip

    def _observe_far(self, t0_ns: int, t1_ns: int, r_B: F64, bg_B: F64 | None,
                     var: float) -> None:  # fmt: skip
        """As ``_observe_offset`` over the far shifts; warn once when one of them halves the
        best misfit of the near shifts (and by more than 25): stamps seconds off."""
        o = self.options
        if not self._far.add(self.history, (t0_ns, t1_ns, r_B, bg_B, var)):
            return
        if self.warned_offset or self.far_frames < o.min_frames or self.offset_frames == 0:
            return
        c_far = self._far.chi2
        k = int(np.argmin(c_far))
        # per frame, so the near sums (over their own frames) and the far ones compare
        near = float(np.min(self._offset_chi2)) / self.offset_frames
        best = float(c_far[k]) / self.far_frames
        # After the axes were told wrong only a shift that explains the turns counts: stamps
        # seconds off move the axes too (told first), a wrong mount's best far shift does not
        # (it named "+1.83 s" as a second cause: a user's probe).
        explains = not self.warned or best / 3.0 <= o.offset_max_fit
        if best < 0.5 * near and (near - best) * self.far_frames > 25.0 and explains:
            self.warned_offset = True
            shift = float(self._far.shifts_s[k])
            log.warning(
                "the camera's turns match the gyro's best with the IMU about %.2f s %s the "
                "camera stamps (%d turning frames): are the images stamped on the IMU's clock? "
                "Give timeshift_cam_imu: %+.2f (t_imu = t_cam + shift%s) in the camera "
                "calibration, or measure it", abs(shift), "after" if shift > 0 else "before",
                self.far_frames, self.applied_shift_s + shift, self._added(shift, 2),
            )  # fmt: skip

    def _added(self, shift: float, digits: int) -> str:
        """How the shift to give is made of the one applied and ``shift``, when one was."""
        if self.applied_shift_s == 0.0:
            return ""
        return (f"; the calibration's {self.applied_shift_s:+.{digits}f} with "
                f"{shift:+.{digits}f} added")

    @property
    def _offset_chi2(self) -> F64:
        """Misfit (S,) per shift between the camera's turns and the gyro's scaled by the best
        common factor at that shift (``Σ |c|² - (Σ g·c)² / Σ |g|²``): a camera that turns a
        few per cent more or less than the gyro (a focal length off) does not pull the shift."""
        return self._near.chi2

    def turn_scale(self) -> tuple[float, float] | None:
        """How far the camera turns per radian of the gyro's turn at the best shift, and its
        standard deviation (scaled by the misfit per degree of freedom when above 1); None
        before any frame."""
        if self.offset_frames == 0:
            return None
        k = int(np.argmin(self._offset_chi2))
        fit = self.offset_fit() or 0.0
        gg = self._near.gg[k]
        return float(self._near.gc[k] / gg), float(np.sqrt(max(fit, 1.0) / gg))

    def _judge_scale(self) -> None:
        """Warn once when the camera turns clearly more or less than the gyro (a few per cent
        up to the factor the turn ratio's band takes: a focal length off, or the gyro's scale)."""
        o = self.options
        got = self.turn_scale()
        fit = self.offset_fit()
        if (self.warned_scale or self.warned_ratio or self.warned or got is None
                or fit is None):  # fmt: skip
            self._held("scale", False)
            return
        scale, std = got
        off = abs(scale - 1.0)
        poor = fit > o.offset_max_fit
        if not self._held("scale", o.scale_warn <= off and off > 4.0 * std and 0.5 < scale < 2
                          and not (poor and off < o.poor_fit_scale_warn)):  # fmt: skip
            return
        if poor:
            # Turns that fit poorly with one clearly off scale: the lens model rather than a
            # focal length (a fisheye read as radtan turned 0.85 times as far at misfit 180,
            # unsaid, 4.5 m off; the only warning blamed the IMU's axes: a user's probe).
            self.warned_scale = self.warned_lens = True
            log.warning(
                "the camera turns %.3f ± %.3f times as far as the gyro, and its turns fit the "
                "gyro's poorly (misfit %.0f per degree of freedom, %d turning frames): is the "
                "lens model right (distortion_model: a fisheye read as radtan, or none?) and "
                "are the intrinsics?", scale, std, fit, self.offset_frames,
            )  # fmt: skip
            return
        self.warned_scale = True
        log.warning(
            "the camera turns %.3f ± %.3f times as far as the gyro (%d turning frames): are the "
            "camera's intrinsics right? A focal length (fu, fv) %.0f %% too %s turns it so "
            "(about the optical axis excepted), and so does a gyro scale factor off",
            scale, std, self.offset_frames, abs(100.0 * (1.0 / scale - 1.0)),
            "large" if scale < 1.0 else "small",
        )  # fmt: skip

    def _held(self, what: str, calls: bool) -> bool:
        """Whether the judgement ``what`` has called for a warning (``calls``) at every turning
        frame over the last ``min_frames``: the first turning frames of a slow turn on a noisy
        gyro read 67 ± 7 ms and 0.972 ± 0.006 where the stamps and the lens were right (-8 ±
        4 ms and 1.001 ± 0.007 after 25 frames: a user's probe)."""
        if not calls:
            self._flagged_at.pop(what, None)
            return False
        first = self._flagged_at.setdefault(what, self.offset_frames)
        # at the run's end a call that has held over half as many is told (a review: a 50 ms
        # offset read 47.8 ± 0.4 ms over 18 turning frames went unsaid)
        need = self.options.min_frames // 2 if self._at_end else self.options.min_frames
        return self.offset_frames - first >= need

    def _tell_unconfirmed(self) -> None:
        """At the run's end, a call that had no time to hold is said as such (once): too few
        turning frames to confirm it, too strong to leave unsaid."""
        offset, scale = self.time_offset(), self.turn_scale()
        if "offset" in self._flagged_at and not self.warned_offset and offset is not None:
            self.warned_offset = True
            log.warning("over the last turning frames of the run (%d in all) the camera's turns "
                        "matched the gyro's best with the IMU %.0f ms %s the camera stamps (± "
                        "%.0f ms), too few frames to confirm it: check timeshift_cam_imu on a "
                        "recording with more turns", self.offset_frames, abs(offset[0]) * 1e3,
                        "after" if offset[0] > 0 else "before", offset[1] * 1e3)  # fmt: skip
        if "scale" in self._flagged_at and not self.warned_scale and scale is not None:
            self.warned_scale = True
            log.warning("over the last turning frames of the run (%d in all) the camera turned "
                        "%.3f ± %.3f times as far as the gyro, too few frames to confirm it: "
                        "check the camera's intrinsics on a recording with more turns",
                        self.offset_frames, scale[0], scale[1])  # fmt: skip

    def _flush_offsets(self) -> None:
        """Judge the frames held for IMU samples past their shifted intervals, now there."""
        t = self.history.t_ns
        if not t.size:
            return
        for frame in self._near.ready(int(t[-1])):
            self._observe_offset(*frame)
        for frame in self._far.ready(int(t[-1])):
            self._observe_far(*frame)

    def time_offset(self) -> tuple[float, float] | None:
        """The shift ``δ`` (s) of the IMU's clock against the camera stamps that best matches
        their turns (``t_imu = t_cam + δ``, Kalibr's ``timeshift_cam_imu`` still missing from
        the calibration) and its standard deviation (from the misfit's curvature, scaled by the
        misfit per degree of freedom when above 1), or None
        before any frame or with the best shift at the edge of those tried (beyond them)."""
        if self.offset_frames == 0:
            return None
        c = self._offset_chi2
        k = int(np.argmin(c))
        if k == 0 or k == c.size - 1:
            return None
        curv = c[k - 1] - 2.0 * c[k] + c[k + 1]
        if not curv > 0.0:
            return None
        step = self.options.offset_step_s
        shift = self._near.shifts_s[k] + 0.5 * step * (c[k - 1] - c[k + 1]) / curv
        # chi-square curvature: d²χ²/dδ² = 2 / σ², scaled by the misfit per degree of freedom
        # when above 1 (turns the noise does not explain: a gyro bias the filter has wrong)
        scale = max(self.offset_fit() or 0.0, 1.0)
        return float(shift), float(np.sqrt(2.0 * step**2 / curv * scale))

    def offset_fit(self) -> float | None:
        """The misfit per degree of freedom between the camera's and the gyro's turns at the
        best shift and scale (about 1 where the mount and the noise are right; None before
        any frame)."""
        if self.offset_frames == 0:
            return None
        return float(np.min(self._offset_chi2)) / max(3 * self.offset_frames - 1, 1)

    def summary(self) -> dict[str, object]:
        """``frames`` compared, the ``median_axis_deg`` and ``median_turn_ratio`` (gyro over
        camera; None before any), and whether each was warned; the camera stamps' best
        ``time_offset_ms`` against the gyro and its ``time_offset_std_ms`` (None: none found
        inside ±300 ms) and whether it was warned."""
        self._flush_offsets()
        if self.time_offset() is None:
            self._judge_edge()  # the end: far shifts still waiting for samples never come
        if self._flagged_at and self.offset_frames >= self.options.min_frames:
            # calls still waiting to hold: no more frames will come
            self._at_end = True
            try:
                self._judge_scale()
                self._judge_offset()
            finally:
                self._at_end = False
            self._tell_unconfirmed()
            if not self.warned_offset:
                self._flagged_at.pop("offset", None)
                self._judge_axes()  # held back for it
        a, r = self.angles_deg, self.ratios
        offset, scale, mount = self.time_offset(), self.turn_scale(), self.mount_error()
        return {"frames": len(a), "median_axis_deg": float(np.median(a)) if a else None,
                "median_turn_ratio": float(np.median(r)) if r else None,
                "warned": self.warned, "warned_turn_ratio": self.warned_ratio,
                "time_offset_ms": None if offset is None else offset[0] * 1e3,
                "time_offset_std_ms": None if offset is None else offset[1] * 1e3,
                "time_offset_fit": self.offset_fit(),
                "warned_time_offset": self.warned_offset,
                "turn_scale": None if scale is None else scale[0],
                "turn_scale_std": None if scale is None else scale[1],
                "warned_turn_scale": self.warned_scale,
                "mount_error_deg": None if mount is None else mount[0],
                "mount_error_std_deg": None if mount is None else mount[1],
                "warned_mount": self.warned_mount}  # fmt: skip


_NO_SHIFT = np.zeros(1)
# A direction of mount rotation counts as seen by the turns when its information is at least
# this fraction of the best-seen direction's.
MOUNT_MIN_INFO = 0.1


class _ShiftSums:
    """Per shift ``δ`` of ``shifts_s`` (S,) s, over the turning frames added: the gyro's turn
    over ``[t0 + δ, t1 + δ]`` squared (``gg``), its product with the camera's (``gc``), and the
    camera's turn squared (``cc``), each over the frame's noise; frames whose farthest shifted
    interval the IMU has not reached yet wait in ``pending``."""

    def __init__(self, shifts_s: F64) -> None:
        self.shifts_s = shifts_s
        self.gg = np.zeros(shifts_s.size)
        self.gc = np.zeros(shifts_s.size)
        self.cc = 0.0
        self.frames = 0
        self.pending: list[_Frame] = []

    def _span_ns(self, frame: _Frame) -> tuple[int, int]:
        return frame[0] + int(self.shifts_s[0] * 1e9), frame[1] + int(self.shifts_s[-1] * 1e9)

    def add(self, h: ImuHistory, frame: _Frame) -> bool:
        """Add ``frame`` (t0_ns, t1_ns, camera turn (3,) rad in body axes, gyro bias or None,
        noise variance); False when it waits for samples, or cannot be judged (the samples
        before it gone, or a shifted interval over dropped or missing ones)."""
        t0_ns, t1_ns, r_B, bg_B, var = frame
        t = h.t_ns
        lo, hi = self._span_ns(frame)
        if t.size < 2 or t[0] > lo:
            return False
        if t[-1] < hi:
            self.pending.append(frame)
            return False
        if h.fault_in(lo, hi):
            return False
        turns = _gyro_turns(t, h.gyro_B, t0_ns, t1_ns, bg_B, self.shifts_s)
        self.gg += np.sum(turns * turns, axis=1) / var
        self.gc += (turns @ r_B) / var
        self.cc += float(r_B @ r_B) / var
        self.frames += 1
        return True

    def ready(self, end_ns: int) -> list[_Frame]:
        """The pending frames the IMU samples up to ``end_ns`` now cover (taken out)."""
        ready = [f for f in self.pending if end_ns >= self._span_ns(f)[1]]
        self.pending = [f for f in self.pending if end_ns < self._span_ns(f)[1]]
        return ready

    @property
    def chi2(self) -> F64:
        """Misfit (S,) per shift at the best common scale: ``cc - gc² / gg``."""
        return self.cc - self.gc**2 / np.maximum(self.gg, 1e-300)


def _gyro_turns(t_ns: NDArray[np.int64], gyro_B: F64, t0_ns: int, t1_ns: int,
                bg_B: F64 | None, shifts_s: F64) -> F64:  # fmt: skip
    """The gyro's rates (bias ``bg_B`` removed) integrated over ``[t0_ns + δ, t1_ns + δ]`` for
    each shift ``δ`` of ``shifts_s`` (S,) s: (S, 3) rad, the rotation vector of the turn to
    second order (``∫ω dt + ½∫θ × ω dt``, θ the turn since the window's start: the
    Baker-Campbell-Hausdorff term of composing body rates), over one cumulative integral with
    the ends interpolated; unlike the log of the composed rotation, not wrapped past π (a gyro
    read in deg/s turns by radians between two frames). The first order alone was 1.6-2.5° off
    on a MAV's 22-24° turns 0.65 s long: the mount estimate read 1.72° ± 0.25° on a right
    mount, the stamp and scale tests stood silent on misfits of 30-126 (a user's probe)."""
    lo = t0_ns + int(shifts_s[0] * 1e9)
    hi = t1_ns + int(shifts_s[-1] * 1e9)
    i0 = max(int(np.searchsorted(t_ns, lo, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(t_ns, hi, side="left")) + 1, t_ns.size)
    t = (t_ns[i0:i1] - t0_ns) * 1e-9
    w = gyro_B[i0:i1] - (0.0 if bg_B is None else bg_B)
    end = (t1_ns - t0_ns) * 1e-9
    first = shifted_integrals(t, w, end, shifts_s)
    if t.size < 2:
        return first
    # per sample step, rates linear between samples: ∫θ × ω = Θ_k × Δθ_k + (w_k × w_k+1) h²/6
    h = np.diff(t)[:, None]
    step = 0.5 * (w[1:] + w[:-1]) * h
    theta = np.vstack([np.zeros(3), np.cumsum(step, axis=0)])
    cone = np.cross(theta[:-1], step) + np.cross(w[:-1], w[1:]) * h**2 / 6.0
    cum = np.vstack([np.zeros(3), np.cumsum(cone, axis=0)])

    def at(c: F64, ts: F64) -> F64:
        return np.stack([np.interp(ts, t, c[:, i]) for i in range(3)], axis=1)

    th_s, th_e = at(theta, shifts_s), at(theta, end + shifts_s)
    # the window's own turn: θ measured from its start, θ(t) - θ(t_s)
    second = first + 0.5 * ((at(cum, end + shifts_s) - at(cum, shifts_s))
                            - np.cross(th_s, th_e - th_s))  # fmt: skip
    # The series holds for turns well below π: beyond, the first order is kept (a gyro read in
    # deg/s turns 57 times as far, where the second order bent the axes 40-50° and the ratio
    # to 69-76: a user's probe)
    big = np.linalg.norm(first, axis=1) > 0.5 * np.pi
    return np.where(big[:, None], first, second)


def rotation_check(history: ImuHistory | None, R_B_C: F64, imu: ImuCalib | None,
                   applied_shift_s: float = 0.0) -> RotationCheck | None:  # fmt: skip
    """A check of ``R_B_C`` on ``history``'s gyro (noise from ``imu``, else the filter's
    default; the stamps moved by ``applied_shift_s`` s), or None without an IMU."""
    if history is None:
        return None
    return RotationCheck(history, R_B_C, (imu or default_imu_calib()).gyro_noise_density,
                         applied_shift_s=applied_shift_s)  # fmt: skip
