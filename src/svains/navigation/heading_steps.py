"""The heading steps of ``navigator_core.Core``: the GPS heading check and the heading wait.

``HeadingSteps`` is a mixin of ``Core``: a start without a heading source held in a local frame
until the GPS gives the heading (``navigation.heading_wait``), the check that turns a heading
the GPS velocities show wrong (``navigation.heading_check``), and the GPS antenna's position
they pivot about. It uses what ``Core`` sets before ``_init_heading``: ``ins``, ``rig``,
``config``, ``init_info``, ``t0_ns``, ``_up_W``, ``_warn``, ``_imu_fault_since``, the logs
(``_log_x``, ``_log_std``, ``_log_P9``), ``_updater`` and ``_mag_off``.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from scipy.stats import chi2

from svains.geometry.rotation import quat_to_rotmat, skew, so3_exp, so3_log
from svains.models.gps import gps_position, gps_velocity
from svains.models.state import DP, DTH, DV, Q, V
from svains.models.state import P as POS
from svains.models.vision_clone import body_displacement
from svains.navigation.base import MeasurementBlock
from svains.navigation.heading_check import (
    HeadingCheck,
    HeadingCheckOptions,
    HeadingError,
    horizontal,
    turn_heading,
    turn_sensitivity,
    widen_position,
    yaw_std,
)
from svains.navigation.heading_wait import HEADING_WAIT_MAX_S, FixPathHeading, turn_logged
from svains.navigation.init import ARBITRARY, HEADING_BANK, HEADING_FROM_GPS, VELOCITY_UNKNOWN
from svains.navigation.ins import default_imu_calib
from svains.navigation.options import RunConfig
from svains.navigation.outputs import FrameTurn
from svains.navigation.vision import LcUpdater, PixelUpdater
from svains.navigation.vision_egomotion import tracks_egomotion
from svains.navigation.yaw_bank import YAW_BANK_MAX_S, YawBank, bank_yaw, level_axis
from svains.sensors.types import Rig

log = logging.getLogger(__name__)

# RANSAC's egomotion covariance takes the k-1 points as exact: on recorded features its NEES is
# 18-29 for 6 dof (``VisionOptions.lc_scale``, whose 30 also covers the correlation between
# consecutive egomotions, which the heading check's velocities a fix apart do not share).
CAMERA_VELOCITY_COV_SCALE = 4.0
# s: how far a GPS velocity's stamp may be from its instant (a receiver's filter and latency).
# In a turn the velocity turns by the rate times that: a camera velocity compared with a GPS
# velocity 0.3 s late in a 150°/s turn read a wrong heading of 21-33° (a review), which the
# row's variance now holds; straight on it adds nothing.
GPS_VELOCITY_TIMING_S = 0.2
# A turned state's position this far from the fix (chi-square probability, 3 dof) was not
# held by the fixes: it is widened to the fix (``widen_position``).
POSITION_OFF_PROBABILITY = 0.999


class HeadingSteps:
    """The heading check and the heading wait of ``Core`` (the module docstring)."""

    def _init_heading(self, config: RunConfig, rig: Rig, init_info: dict[str, Any],
                      gps_used: bool) -> None:  # fmt: skip
        """The heading check and, for a start whose heading the GPS will give
        (``init.HEADING_FROM_GPS``), the wait's state (Core's ``__init__``, once ``ins``,
        ``_up_W``, ``t0_ns`` and the logs are set)."""
        self._heading_check = (
            HeadingCheck(self._up_W, rig.gps.velocity_noise_std,
                         (rig.imu or default_imu_calib()).accel_noise_density)
            if gps_used and rig.gps is not None and config.use_gps_velocity
            and config.faults.heading_check else None
        )  # fmt: skip
        self._heading_fixes: list[Any] = []  # (t, v_W_G) of this group's GPS velocities
        # the frames since the last fix: tracks, R_W_B (3, 3), lever-arm velocity (3,) m/s, the
        # camera mount the state holds (``_mount``)
        self._frames_since_fix: list[tuple[Any, np.ndarray, np.ndarray, Any]] = []
        # position-only fixes during the heading wait: the heading from their path
        check = HeadingCheckOptions()
        self._fix_path = FixPathHeading(
            self._up_W, rig.gps.position_noise_std if rig.gps is not None else 1.0,
            np.radians(check.max_std_deg), check.fit_probability)
        # A start without a heading source runs in a local frame about its GPS antenna until
        # the GPS gives the heading; fixes wait (``navigation.heading_wait``).
        self._heading_wait = init_info.get("heading") == HEADING_FROM_GPS
        # a ``gps`` start in motion, its horizontal velocity's direction unknown there
        self._start_moving = VELOCITY_UNKNOWN in init_info
        self._heading_pivot = self._antenna_W()
        # the antenna's own motion during the wait (the filter's predictions and vision, not
        # the fixes fused meanwhile: ``_wait_fix``), counted from ``_own_from_W_A``
        self._own_L_A = np.zeros(3)
        self._own_from_W_A = self._heading_pivot.copy()
        self._own_fix_fused = False
        self._heading_wait_from: int | None = None  # first fix held after setting off
        self._heading_held_t: list[int] = []  # the held fixes' times
        self.gps_held_heading = 0
        self.frame_turns: list[FrameTurn] = []
        if self._heading_wait and not config.faults.heading_check:
            self._end_heading_wait(self.t0_ns, "the heading check is off")
        # an INS started in motion with no heading: a bank of headings the fixes weigh
        bank_n = config.init.yaw_bank_models
        self._yaw_bank: YawBank | None = None
        if (bank_n and gps_used and rig.gps is not None and config.method == "ins"
                and init_info.get("mode") == "gps" and init_info.get("heading") == ARBITRARY):
            # the start's specific force, which its attitude was levelled on
            a_W = np.asarray(init_info.get("gps_acceleration_W", np.zeros(3)), dtype=float)
            self._yaw_bank = YawBank(self.ins, self._up_W, a_W - np.asarray(rig.gravity_W),
                                     rig.gps.p_B_G, bank_n, config.init.yaw_bank_max_std)
            init_info["heading"] = HEADING_BANK
            log.warning("a bank of %d headings weighs the GPS fixes until they show the "
                        "heading (the estimates' yaw uncertainty is the bank's spread "
                        "meanwhile)", bank_n)  # fmt: skip

    def _bank_fix(self, t: int, block: MeasurementBlock) -> bool:
        """A measurement (a GPS fix, a sonar range) to the bank of headings
        (``navigation.yaw_bank``), if one runs: True, the bank took it (its copies fuse it;
        the filter follows the heaviest copy, and the estimate logged is the mixture's:
        ``_estimate``). Once the heading is known the merged copies replace the filter,
        reported as the heading found; a bank with none after ``YAW_BANK_MAX_S`` stops
        (the filter stays the heaviest copy), warned."""
        bank = self._yaw_bank
        if bank is None:
            return False
        stats = bank.update(block, self.config.filter.gate_probability, t)
        if stats is not None:
            self._record(stats, block.name, t)
        if not bank.alive:  # every copy failed numerically: the filter goes on as it is
            self._bank_gave_up(t, "every copy of the bank of headings failed")
            return False
        merged = bank.merged()
        if merged is None:
            self._follow_heaviest()
            return True
        ukf = self.ins.ukf
        axis = level_axis(ukf.x, self._up_W)
        yaw_before = bank_yaw(ukf.x, self._up_W, axis)
        ukf.x, ukf.P = merged.x, merged.P
        self._bank_over()
        turn = float(np.angle(np.exp(1j * (bank_yaw(ukf.x, self._up_W, axis) - yaw_before))))
        at_s = (t - self.t0_ns) * 1e-9
        self.init_info.update(heading_found_s=round(at_s, 3),
                              heading_turn_deg=round(float(np.degrees(turn)), 3),
                              heading_std_deg=round(float(np.degrees(merged.std_rad)), 3),
                              heading_source=f"a bank of {len(bank.members)} headings "
                                             f"over {merged.fixes} GPS fixes")  # fmt: skip
        log.info("%.3f s into the run: heading from a bank of %d headings over %d fixes: "
                 "turned by %.1f° (± %.1f°)", at_s, len(bank.members), merged.fixes,
                 np.degrees(turn), np.degrees(merged.std_rad))  # fmt: skip
        return True

    def _bank_propagate(self, t: int, Q9: np.ndarray | None) -> None:
        """The bank of headings' copies to ``t`` (an IMU gap's covariance ``Q9`` added); it
        ends when no copy is left, or after ``YAW_BANK_MAX_S`` without a heading (checked
        here too: without fixes nothing else reaches it), the filter then the likeliest
        copy."""
        bank = self._yaw_bank
        assert bank is not None
        bank.propagate(t, Q9)
        if not bank.alive:
            self._bank_gave_up(t, "every copy of the bank of headings failed")
        elif (t - self.t0_ns) * 1e-9 > YAW_BANK_MAX_S:
            self._follow_heaviest()
            self._bank_gave_up(t, f"no heading from the GPS fixes over {YAW_BANK_MAX_S:g} s: "
                               "the likeliest of the bank's headings is kept")  # fmt: skip

    def _follow_heaviest(self) -> None:
        """The filter becomes the bank's likeliest copy (no recovery acts on it while the bank
        runs: it is written over at each fix)."""
        assert self._yaw_bank is not None
        heaviest = self._yaw_bank.heaviest()
        self.ins.ukf.x, self.ins.ukf.P = heaviest.x.copy(), heaviest.P.copy()

    def _bank_gave_up(self, t: int, why: str) -> None:
        """The bank of headings ends without a heading (``why``): warned with its spread,
        which ``report.json`` keeps (``init.heading_bank_std_deg``)."""
        assert self._yaw_bank is not None
        spread = "no copy left"
        if self._yaw_bank.alive:
            std = float(np.degrees(self._yaw_bank.heading()[1]))
            self.init_info["heading_bank_std_deg"] = round(std, 3)
            spread = f"the bank's yaw uncertainty {std:.0f}°"
        self._warn.warn("heading-bank", t, f"{why} ({spread}; only acceleration shows the "
                        "heading, and a magnetometer would give it)")  # fmt: skip
        self._bank_over()

    def _bank_over(self) -> None:
        """The bank of headings ends (merged, or given up): the heading check starts again
        and the consistency monitor's bias test forgets the innovations it held."""
        self._yaw_bank = None
        if self._heading_check is not None:
            self._heading_check.restart()
        if self._recovery is not None:
            self._recovery.state_replaced(self.ins.ukf)

    def _estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The estimate to log and emit: the state's mean (nx,), its covariance (ndx, ndx)
        and tangent standard deviations (ndx,); while a bank of headings runs, its heaviest
        copy's with the mixture's covariance (``YawBank.about_heaviest``)."""
        ins = self.ins
        if self._yaw_bank is None:
            return ins.ukf.x, ins.ukf.P, ins.tangent_std()
        x, P = self._yaw_bank.about_heaviest()
        return x, P, np.sqrt(np.maximum(np.diag(P)[: self.layout.ndx], 0.0))

    def _antenna_W(self) -> np.ndarray:
        """The GPS antenna's position (3,) m (the body's without a GPS): the heading wait's
        pivot, where the local frame and the world agree (a start subtracts the lever arm with
        its local heading: turned about the body, a 1.5 m lever arm left the first seconds
        1.2 m off, a user's probe)."""
        x = self.ins.ukf.x
        if self.rig.gps is None:
            return np.array(x[POS], dtype=float)
        return gps_position(x[None, :], self.rig.gps.p_B_G)[0]

    def _check_heading(self, t: int, p_W_G: Any, v_W_G: Any, use_v: bool) -> None:
        """Before a GPS fix's update: turn the state when the velocities since the last fixes
        show its heading wrong (``navigation.heading_check``), warned. Not across an IMU fault
        (a bridged gap predicts no velocity change) nor with a GPS velocity switched off."""
        assert self._heading_check is not None
        ukf = self.ins.ukf
        usable = use_v and not self._imu_fault_since(self._heading_check.last_fix_ns)
        v_var = float(np.trace(ukf.P[DV, DV])) / 3.0
        acquire = self._heading_wait
        # the antenna's velocity, as the fix gives it: the body's differed by R (ω × p_B_G),
        # and with a 1.5 m lever arm the heading was never found (a review)
        assert self.rig.gps is not None
        v_W_A = gps_velocity(ukf.x[None, :], self.rig.gps.p_B_G)[0]
        camera = None if acquire else self._camera_velocity(t)  # (a wait asks for none)
        error = self._heading_check.before_update(t, v_W_A, v_W_G, yaw_std(ukf, self._up_W),
                                                  v_var, usable, acquire, camera)  # fmt: skip
        self._heading_fixes.append((t, np.asarray(v_W_G, float)))
        if error is None:
            return
        if acquire:
            if not self._path_contradicts(t, error):
                self._heading_found(t, error, "the GPS velocities")
            return
        # The fix's velocity replaces the turned one (it is the reference the turn was found
        # against; an INS's velocity error is no rotation of its velocity).
        assert self.rig.gps is not None
        turn_heading(ukf, error, self._up_W, np.asarray(v_W_G, float),
                     self.rig.gps.velocity_noise_std)  # fmt: skip
        # A position dead-reckoned away from the fixes under the wrong heading (refused, they
        # did not hold it) is as unsure as its distance from this fix, which the update then
        # follows (magnetometer turned 90°, `3d` seed 1 without the camera's witness: 9.7 m
        # from the fix at 0.64 m per axis; left so, the fix was refused, the run of refusals
        # read as multipath, 11.6 m). A position the fixes held (an INS's, its velocity changes
        # turned) is left: widened too, `ins` lost 1.13 -> 1.27 m on `bench/mag_mount.py`.
        offset = np.asarray(p_W_G, float) - self._antenna_W()
        S = ukf.P[DP, DP] + self.rig.gps.position_noise_std**2 * np.eye(3)
        if float(offset @ np.linalg.solve(S, offset)) > chi2.ppf(POSITION_OFF_PROBABILITY, 3):
            widen_position(ukf, offset)
        # A heading the magnetometer held (at the start or since) was its: fused on, it would
        # pull the turned state back once the yaw is uncertain (simulator, `ins`, magnetometer
        # turned 90°: back to 110° off 9 s after the turn).
        hint = ""
        if self.rig.mag is not None and self.config.use_mag:
            self._mag_off = True
            hint = ("; the magnetometer is not fused from now on (is its T_BS right? "
                    "svains reads its field in the body frame through it)")
        if error.witness == "camera":
            # In straight flight a camera turned about the vertical on its mount looks the
            # same as a wrong heading (simulated village, camera turned 90°: turned 90° wrong)
            hint += ("; a camera turned about the vertical on its mount would look the same "
                     "(is the camera's T_BS right?)")
        # A GPS refused as jumped while the heading was wrong (the wrong heading's dead
        # reckoning ran off from it) had not jumped: heard again. Simulated village 30 s,
        # magnetometer turned 90°, `3d`: the fixes stayed refused to the end (seed 3 without
        # sonar 10.97 m, seed 5 12.0 / 12.6 m with / without, against about 1 m clean).
        recovery = self._acting_recovery
        # (a reset from the next fix as well was tried and lost elsewhere: its height
        # against the sonar's)
        if recovery is not None and (names := recovery.monitor.withdraw_jumps()):
            hint += f"; {', '.join(names)}, refused as jumped meanwhile, is heard again"
        self._warn.warn("heading-turn", t, f"the heading was {np.degrees(error.angle_rad):.1f}° "
                        f"off (± {np.degrees(error.std_rad):.1f}°, from {error.source()} "
                        f"over {error.steps} fixes): the state is turned{hint}")  # fmt: skip

    def _camera_velocity(self, t: int) -> tuple[int, np.ndarray, float] | None:
        """For the heading check at a fix at ``t``: the GPS antenna's mean velocity (3,) m/s
        over a frame pair since the previous fix, as the camera measured it (its egomotion) in
        the filter's world (turned by the filter's attitude at that frame, so by its heading
        error), the pair's middle (ns) and the velocity's variance per axis (m²/s²; the
        egomotion's, scaled by ``CAMERA_VELOCITY_COV_SCALE``); of the frames since the previous
        fix, the pair whose middle is nearest the middle between the fixes (the check compares
        it with the two fixes' velocities interpolated there). None without a vision method's
        frame pair or its egomotion."""
        frames, self._frames_since_fix = self._frames_since_fix, []
        assert self._heading_check is not None
        t_prev = self._heading_check.last_fix_ns
        if not frames or t_prev < 0:
            return None
        mid = 0.5 * (t_prev + t)
        tr, R_W_B, lever_W, mount = min(
            frames, key=lambda f: abs(0.5 * (f[0].t_ns + f[0].t_prev_ns) - mid))
        updater = self._updater
        assert isinstance(updater, (PixelUpdater, LcUpdater))
        ego = tracks_egomotion(tr, updater.rig, seed=0)  # the front end's, or RANSAC's
        if ego is None:
            return None
        var_p = float(np.trace(np.asarray(ego.cov, float)[3:, 3:])) / 3.0
        if not np.isfinite(var_p):
            return None
        dt_s = (tr.t_ns - tr.t_prev_ns) * 1e-9
        # the camera's rotation on the body as the filter holds it, when it estimates (or
        # considers) one: with the calibration's the velocities of a camera 25° off on its
        # mount, being estimated, turned a right heading 25° (a review)
        R_B_C = None if mount is None else updater.rig.R_B_C @ so3_exp(mount[0])
        v_W_B = R_W_B @ body_displacement(ego.R_Ck_Ckm1, ego.p_Ck_Ckm1, updater.rig,
                                          R_B_C) / dt_s  # fmt: skip
        var = CAMERA_VELOCITY_COV_SCALE * var_p / dt_s**2
        speed2 = float(v_W_B @ v_W_B)
        if mount is not None:  # its rotation's spread turns the velocity too
            var += float(np.trace(mount[1])) / 3.0 * speed2
        rate = float(np.linalg.norm(so3_log(ego.R_Ck_Ckm1))) / dt_s
        var += (GPS_VELOCITY_TIMING_S * rate) ** 2 * speed2
        return (tr.t_ns + tr.t_prev_ns) // 2, v_W_B + lever_W, var

    def _note_frame(self, t: int) -> None:
        """After a frame at ``t``: its tracks with the filter's attitude and the antenna's
        lever-arm velocity there (``_camera_velocity``), while the heading check runs."""
        updater = self._updater
        if (self._heading_check is None or self.rig.gps is None
                or not isinstance(updater, (PixelUpdater, LcUpdater))):  # fmt: skip
            return
        tr = updater.last_tracks
        if tr is None or tr.t_ns != t or tr.t_ns <= tr.t_prev_ns:
            return
        ukf = self.ins.ukf
        x = ukf.x
        lever_W = gps_velocity(x[None, :], self.rig.gps.p_B_G)[0] - x[V]
        # only pairs a fix step long can be compared (without fixes the list would grow)
        keep_ns = int(self._heading_check.options.max_step_s * 1e9)
        self._frames_since_fix = [f for f in self._frames_since_fix if t - f[0].t_ns <= keep_ns]
        self._frames_since_fix.append((tr, quat_to_rotmat(x[Q]), lever_W, self._mount(updater)))

    def _mount(self, updater: PixelUpdater | LcUpdater) -> tuple[np.ndarray, np.ndarray] | None:
        """The camera rotation correction ``δφ_C`` (3,) rad the state holds and its covariance
        (3, 3), when a vision method estimates or considers it (``vision_clones``); else None."""
        clones = getattr(updater, "clones", None)
        ukf = self.ins.ukf
        if clones is None or clones.calib(ukf) is None:
            return None
        cx, cdx = ukf.manifold.calib  # type: ignore[attr-defined]
        a, b = cx.start, cdx.start
        return ukf.x[a:a + 3].copy(), ukf.P[b:b + 3, b:b + 3].copy()

    def _path_contradicts(self, t: int, error: HeadingError) -> bool:
        """Whether the fixes' own path (``FixPathHeading``, their positions) gives a heading
        beyond 3σ of the velocities' ``error``: then the velocities are no heading (warned,
        the wait goes on). Velocities reversed through a wait were taken for a 180° turn the
        positions contradicted, and `3d` ran 10-26 m off for 8 s (a user's probe)."""
        path = self._fix_path.estimate(math.pi)
        if path is None:
            return False
        off = math.remainder(error.angle_rad - path.angle_rad, 2.0 * math.pi)
        if abs(off) <= 3.0 * math.hypot(error.std_rad, path.std_rad):
            return False
        deg = math.degrees
        self._warn.warn("heading-wait", t, f"the GPS velocities turn the heading by "
                        f"{deg(error.angle_rad):.0f}° (± {deg(error.std_rad):.0f}°), the fixes' "
                        f"positions by {deg(path.angle_rad):.0f}° (± {deg(path.std_rad):.0f}°): "
                        "no turn from them; the wait goes on")  # fmt: skip
        return True

    def _wait_fix(self, t: int, p_W_G: Any, v_W_G: Any) -> bool:
        """During the heading wait, a fix (``v_W_G`` None: position only, or its velocity not
        fused): whether it shows the vehicle standing, and the fixes' path with the filter's
        own (``FixPathHeading``, started again after an IMU fault, whose bridge breaks the
        filter's path), which gives a position-only fix's heading and turns the state (with
        velocities the heading check is surer sooner, KITTI raw ±0.3° at the fourth fix
        against ±1.8° at the third, and the path's serves at the wait's end:
        ``_take_path_heading``). Standing, before the vehicle first set off (a ``gps`` start
        in motion never is): the GPS's horizontal speed within 3σ of its velocity noise;
        without a velocity, the antenna's own motion since the wait began within half a fix's
        σ, where any heading error moves it by less than the fix's noise (judged from fix to
        fix, a vehicle slower than σ per fix interval, 14 m/s at 10 Hz, stood for good: a
        user's probe)."""
        assert self.rig.gps is not None
        ukf = self.ins.ukf
        if self._imu_fault_since(self._fix_path.last_ns):
            self._fix_path.clear()
        # the filter's path is its own motion: with the fixes fused while standing in it, a
        # 10 Hz GPS dragged it onto the fixes and the fit took a turn 58° off (a user's probe)
        p_W_A = self._antenna_W()
        self._own_L_A += p_W_A - self._own_from_W_A
        self._own_from_W_A = p_W_A
        if v_W_G is None:
            moved, limit = self._own_L_A, 0.5 * self.rig.gps.position_noise_std
        else:
            moved, limit = np.asarray(v_W_G, float), 3.0 * self.rig.gps.velocity_noise_std
        # Fused only at the pivot, where the local frame and the world agree: before the
        # vehicle first set off (a stop after it, fused, moved the state 3-5 m: a user's
        # probe). A start in motion is never there; and its own motion began at a zeroed
        # velocity, so its first position-only fixes passed as standing at 4.3 m/s (a review:
        # 2.37 m, NEES 22.5)
        standing = (not self._start_moving and self._heading_wait_from is None
                    and float(np.linalg.norm(horizontal(moved, self._up_W))) <= limit)
        # with velocities the path is fitted only at the wait's end
        error = self._fix_path.add(t, np.asarray(p_W_G, float), self._own_L_A.copy(),
                                   float(np.trace(ukf.P[POS, POS])) / 3.0, standing,
                                   fit=v_W_G is None)  # fmt: skip
        if error is not None:
            self._heading_found(t, error, "the GPS fixes' path")
        return standing

    def _take_path_heading(self, t: int, why: str) -> bool:
        """At the wait's end without a heading (``why``): the fixes' path's, if it is surer
        than the arbitrary heading's ``init.yaw_std_unknown`` and fits, is taken
        (the state and what it logged turned), warned with its uncertainty. Whether it was."""
        error = self._fix_path.estimate(self.config.init.yaw_std_unknown)
        if error is None:
            return False
        self._heading_found(t, error, "the GPS fixes' path, at the wait's end")
        self._warn.warn("heading-wait", t, f"{why}: the heading from the path of the GPS fixes "
                        f"is taken, known to ± {np.degrees(error.std_rad):.1f}° only (a "
                        "magnetometer or GPS velocities would give it sooner)")  # fmt: skip
        return True

    def _hold_for_heading(self, t: int, standing: bool) -> bool:
        """While a local start waits for its heading: a fix that shows the vehicle
        ``standing`` before it set off (``_wait_fix``) is fused (at rest there the local
        frame and the world agree at the body), and the frame's pivot follows the body; any
        other is held out (counted) until the wait is over (``_heading_wait_over``); then the
        wait ends (``_end_heading_wait``) and it is fused. The IMU's rest test is not asked:
        it ended on a vehicle parked for a minute, and the fixes were held while it stood (a
        user's probe)."""
        if standing:  # (before setting off: ``_wait_fix``)
            self._heading_pivot = self._antenna_W()
            self._own_fix_fused = True
            return False
        if self._heading_wait_from is None:
            self._heading_wait_from = t
        self._heading_held_t.append(t)
        if self._heading_wait_over(t):
            self._end_heading_wait(t, f"the GPS gave none over {HEADING_WAIT_MAX_S:g} s of "
                                   "motion")  # fmt: skip
            return False
        self.gps_held_heading += 1
        return True

    def _heading_wait_over(self, t: int) -> bool:
        """Whether the heading wait has run ``HEADING_WAIT_MAX_S``: an unaided INS in time since
        the first fix held (it drifts meanwhile), a vision method in held fixes at their own
        spacing (its local frame holds; an outage soon after a vision start, counted in time,
        ended the wait after 2 fixes: KITTI raw 7.08 m, and an INS counted in fixes drifted
        6 s longer: 5.54 -> 13.56 m, two reviews). The spacing is the fixes', not the declared
        rate (10 Hz declared for 1 Hz fixes held every fix of the run: a review)."""
        assert self._heading_wait_from is not None
        if self.config.method == "ins":
            return (t - self._heading_wait_from) * 1e-9 > HEADING_WAIT_MAX_S
        held = np.asarray(self._heading_held_t, dtype=np.int64)
        if held.size < 3:
            return False
        spacing_s = float(np.median(np.diff(held))) * 1e-9
        return held.size > max(3, HEADING_WAIT_MAX_S / max(spacing_s, 1e-3))

    def _heading_found(self, t: int, error: Any, source: str) -> None:
        """The local frame's heading found (from ``source``, for the report): the state, the
        estimates logged so far and the stored keyframes turned into the world about the
        start's position."""
        # the filter's own path's point now, in the local frame (``_wait_fix``'s sum)
        own_L_A = self._own_L_A + self._antenna_W() - self._own_from_W_A
        turn_heading(self.ins.ukf, error, self._up_W, pivot_W=self._heading_pivot)
        self._turn_kept(t, error)
        if self.config.method != "ins":
            self._fuse_held_fixes(t, error, own_L_A)
        self._wait_over()
        at_s = (t - self.t0_ns) * 1e-9
        self.init_info["heading_found_s"] = round(at_s, 3)
        self.init_info["heading_turn_deg"] = round(float(np.degrees(error.angle_rad)), 3)
        self.init_info["heading_std_deg"] = round(float(np.degrees(error.std_rad)), 3)
        self.init_info["heading_source"] = source
        if self.gps_held_heading:
            self.init_info["gps_fixes_held"] = self.gps_held_heading
        log.info("%.3f s into the run: heading from %s over %d fixes, the local frame "
                 "turned by %.1f° (± %.1f°) into the world; %d fix(es) held until then", at_s,
                 source, error.steps, np.degrees(error.angle_rad), np.degrees(error.std_rad),
                 self.gps_held_heading)  # fmt: skip

    def _fuse_held_fixes(self, t: int, error: HeadingError, own_L_A: np.ndarray) -> None:
        """The fixes held while moving, once turned into the world, say where the antenna is
        now (``FixPathHeading.carried_to_now``; ``own_L_A`` (3,) m: the filter's own path's
        point now, before the turn): one horizontal position update, gated as a fix's, linear
        (``UKF.update_linear``) because its error shares the turn's with the turned state
        (their cross-covariance from ``turn_sensitivity``; taken as independent, the update
        was overconfident: a Monte Carlo's position NEES 3.4-3.7 of 3, a review's yaw 1.2-1.3
        per dof). Without it the turned state kept the one fix that placed the start (a
        position-only `3d` start on the simulator, turned 10 m off, its next fixes refused
        until the filter was inflated: 3.59 m, NEES 70). For vision methods
        (``_heading_found``): a carried fix's error is the path's since it, which the state
        shares; vision holds that path, an INS's drifts (a review's Monte Carlo: position NEES
        2.8 of 2 after the update, 1.9 without). Not across an IMU fault since the last fix
        (its bridge breaks the filter's path)."""
        assert self.rig.gps is not None
        ukf = self.ins.ukf
        if self._imu_fault_since(self._fix_path.last_ns):
            return
        held = self._fix_path.carried_to_now(error.angle_rad, own_L_A, t)
        if held is None:
            return
        E = self._fix_path.basis
        x = ukf.x
        R_W_B = quat_to_rotmat(x[Q])
        p_B_G = np.asarray(self.rig.gps.p_B_G, dtype=float)
        H = np.zeros((2, ukf.P.shape[0]))  # the horizontal antenna position's Jacobian
        H[:, DP] = E
        H[:, DTH] = -E @ R_W_B @ skew(p_B_G)  # body-frame attitude error
        # The mean is off by -d_turn δψ for the turn's error δψ, which the turned state
        # carries as a δψ (``turn_sensitivity``): their shared error, Cov(e, v) = -σ² a d_turnᵀ
        a = turn_sensitivity(x, ukf.manifold, self._up_W, self._heading_pivot)
        var_turn = error.std_rad**2
        stats = ukf.update_linear(
            H, held.z_H - E @ self._antenna_W(),
            held.R + var_turn * np.outer(held.d_turn_H, held.d_turn_H),
            -var_turn * np.outer(a, held.d_turn_H), self.config.filter.gate_probability,
            "gps_held")  # fmt: skip
        self._record(stats, "gps_held", t)
        self.init_info["held_fixes_fused"] = held.n if stats.accepted else 0

    def _wait_over(self) -> None:
        """The heading wait ends: its path is dropped and the heading check starts again (its
        velocities were compared in the local frame)."""
        self._heading_wait = False
        self._fix_path.clear()
        if self._heading_check is not None:
            self._heading_check.restart()

    def _turn_kept(self, t: int, error: HeadingError) -> None:
        """Turn what the run kept in the local frame (the estimates logged so far, for a
        smoother too, and the stored keyframes) as the state was: by ``error`` about the
        heading wait's pivot."""
        pivot = self._heading_pivot
        turn_logged(self._log_x, self._log_std, self._log_P9, error, self._up_W, pivot)
        self.frame_turns.append(FrameTurn(t, error.angle_rad, error.std_rad, self._up_W.copy(),
                                          pivot.copy()))  # fmt: skip
        reloc = getattr(self._updater, "relocaliser", None)
        if reloc is not None:
            reloc.memory.turn(error.angle_rad * self._up_W, pivot)

    def _end_heading_wait(self, t: int, why: str) -> None:
        """No heading from the GPS: the start's heading becomes an arbitrary one (its yaw
        widened to ``init.yaw_std_unknown``, and so are the estimates logged so far, by a turn
        of 0° with that uncertainty) and fixes are fused, warned; unless the fixes' path gives
        it better than that (``_take_path_heading``)."""
        if self._take_path_heading(t, why):
            return
        self._wait_over()
        std = self.config.init.yaw_std_unknown
        # about the pivot, as the logged rows below: a state far from it (a start in motion)
        # is off by the unknown turn in position too (a yaw widened alone lost the fixes)
        turn_heading(self.ins.ukf, HeadingError(0.0, std, 0), self._up_W,
                     pivot_W=self._heading_pivot)  # fmt: skip
        if self._log_x:
            # the logged rows were the local frame's with a yaw σ of a known heading: as
            # world-frame rows they hold an arbitrary heading too (they read 52-105σ off)
            self._turn_kept(t, HeadingError(0.0, std, 0))
        self.init_info["heading"] = ARBITRARY
        self._warn.warn("heading-wait", t, f"no heading for the local start ({why}): GPS "
                        f"fixes are fused with an arbitrary heading (standard deviation "
                        f"{np.degrees(std):.1f}°) from now on; a magnetometer would give "
                        "one")  # fmt: skip
