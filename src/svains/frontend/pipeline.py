"""The stereo front end: raw stereo pairs in, ``StereoTracks`` (tracks + egomotion) out.

Per frame: track the previous frame's features (KLT; forward-backward unless the start was
predicted from a motion), seek new corners where tracks have been lost, match tracked and new
features left to right in one pass, estimate egomotion by RANSAC (eqs. 11-12) and apply the
epipolar check.

Rigs that need rectification are tracked on the raw images: only feature pixels are rectified
(and row-search patches resampled), which saves two whole-image remaps per frame; all pixels
handed out (``StereoTracks``) are rectified. The dense disparity methods rectify whole images.

Degenerate frames (missing/dropped, black, saturated, textureless, or frozen: both images equal
to the pair before, to the last grey level) give a ``StereoTracks`` with no features and
``egomotion=None`` and do *not* replace the reference frame, so the next good frame is tracked
against the last good one.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from svains.frontend.egomotion import RansacOptions, estimate_egomotion, warm_up
from svains.frontend.egomotion_bundle import refine_or_keep
from svains.frontend.features import detect_corners
from svains.frontend.images import as_grey, image_problem, texture_std
from svains.frontend.motion_checks import agrees_with_prior, plausible
from svains.frontend.options import HOLD_STATUSES, FrameStats, FrontendOptions
from svains.frontend.reacquire import OrbStereo, Reacquired, Reacquirer, match_global, orb_stereo
from svains.frontend.rectify import StereoRectifier
from svains.frontend.stereo import dense_disparity, match_dense, match_sparse
from svains.frontend.stereo_check import StereoCheck
from svains.frontend.tracking import Pyramid, levels_for_residual, track_klt
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.sensors.types import CameraCalib

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

log = logging.getLogger(__name__)

_WARN_FIRST = 3  # malformed pairs warned one by one; after them, one warning per _WARN_EVERY
_WARN_EVERY = 100
# ORB features kept per keyframe (each ~88 bytes: pixels, point, descriptor): 1000 hold a
# room's view and 500 keyframes stay under 45 MB.
KEYFRAME_ORB_FEATURES = 1000
CHECK_MAX_PAIRS = 10  # good pairs the stereo check may look at before it gives up undecided
# Frames in a row without a motion after which the pairs are looked at again, and at most how
# often (frames): streams crossed mid-run.
RECHECK_AFTER = 5
RECHECK_EVERY = 100
NO_MOTION_STATUSES = frozenset({"no_consensus", "implausible", "contradicts_prior"})


@dataclass
class _Reference:
    """Features of the last good frame (N of them)."""

    t_ns: int
    left: Pyramid
    right: Pyramid
    track_id: NDArray[np.int64]
    uv_left: F64
    uv_right: F64
    p_C_F: F64  # (N, 3) m, triangulated


class StereoFrontend:
    """Stateful stereo front end; ``process`` one raw stereo pair per call."""

    def __init__(self, rectifier: StereoRectifier, options: FrontendOptions | None = None) -> None:
        self.rectifier = rectifier
        self.rig: RectifiedStereo = rectifier.rig
        self.options = options or FrontendOptions()
        self.stats = FrameStats()
        self._ref: _Reference | None = None
        self._next_id = 0
        self._last_motion: Egomotion | None = None
        self._held = 0
        self._failed: list[F64] = []  # unmatched new corners of the last few frames
        self._flow_px = 0.0  # median image motion of the tracked features (at the last search)
        # 90th percentile px of how far the last prior-predicted tracks ended from their
        # predicted starts (NaN: the last frame was not tracked from a motion prior).
        self._prior_residual_px = np.nan
        self._n_after_detect = 0  # reference features right after the last corner search
        self._since_detect = 0  # frames since the last corner search
        self._rng = np.random.default_rng(self.options.ransac.seed)
        # Its own stream: a relocalisation leaves the tracking's draws as they were.
        self._reloc_rng = np.random.default_rng([self.options.ransac.seed, 1])
        # Sparse matching on a rig that needs rectification tracks on the raw images and
        # rectifies only the feature pixels (two whole-image remaps per frame saved); the dense
        # methods need rectified images.
        raw = not rectifier.identity and self.options.stereo.method == "sparse"
        self._geo: StereoRectifier | None = rectifier if raw else None
        self._last_images: tuple[U8, U8] | None = None
        # The raw grey pair before (a frozen camera repeats it) and how many repeats in a row.
        self._raw_before: tuple[U8, U8] | None = None
        self._frozen = 0
        self._malformed = 0  # pairs dropped as no image or of another size
        self._reacquirer = Reacquirer(self.rig, self.options.reacquire)
        # The last good frame processed: time, pyramids, dense disparity (keyframes and
        # relocalisation work on it after ``process`` returned).
        self._frame: tuple[int, Pyramid, Pyramid, F64 | None] | None = None
        # Left and right swapped, rows that do not agree (``stereo_check``): judged on the
        # first good pairs, warned once; a swapped pair gives no tracks. Streams crossed after
        # a first check found them in order are exchanged back (``_exchange``).
        self.stereo_check = StereoCheck()
        self._swapped = False
        self._exchange = False
        self._order_seen = False  # a check decided the streams were in order
        self._frames_seen = 0
        self._no_motion = 0  # frames in a row without a motion (``_watch_stereo``)
        self._rechecked_at = -RECHECK_EVERY
        self._decided_check: StereoCheck | None = None  # the last decided, while rechecking
        warm_up(self.rig)  # compiled RANSAC kernels loaded now, not on the first frame

    @property
    def reference_t_ns(self) -> int | None:
        """Time (ns) of the frame the next one will be tracked against (the last good frame;
        held frames do not replace it), ``None`` before the first good frame."""
        return None if self._ref is None else int(self._ref.t_ns)

    @property
    def last_rectified(self) -> tuple[U8, U8] | None:
        """Rectified left and right images (H, W) of the last good frame (for figures)."""
        if self._last_images is None:
            return None
        if self._geo is None:
            return self._last_images
        return self.rectifier.rectify_pair(*self._last_images)

    def _to_img(self, uv: F64, right: bool = False) -> F64:
        """Rectified pixels (N, 2) -> pixels of the tracked images (raw or rectified)."""
        return uv if self._geo is None else self._geo.unrectify_points(uv, right)

    def _to_rect(self, uv: F64, right: bool = False) -> F64:
        """Pixels (N, 2) of the tracked images -> rectified pixels."""
        return uv if self._geo is None else self._geo.rectify_points(uv, right)

    @classmethod
    def from_calibration(
        cls, cam0: CameraCalib, cam1: CameraCalib, options: FrontendOptions | None = None
    ) -> StereoFrontend:
        """Front end for a raw calibrated pair (rectified internally)."""
        return cls(StereoRectifier.from_calibration(cam0, cam1), options)

    @classmethod
    def from_rig(
        cls, rig: RectifiedStereo, options: FrontendOptions | None = None
    ) -> StereoFrontend:
        """Front end for images already rectified to ``rig`` (no remapping)."""
        return cls(StereoRectifier.for_rectified_rig(rig), options)

    # ------------------------------------------------------------------ helpers
    def _stereo(self, left: Pyramid, right: Pyramid, uv: F64, disp_guess: F64 | None,
                disparity: F64 | None) -> tuple[F64, NDArray[np.bool_]]:
        if disparity is not None:
            return match_dense(disparity, uv, self.options.stereo)
        return match_sparse(
            left, right, uv, self.options.stereo, self.options.klt, disp_guess, self._geo
        )

    def _empty(self, t_ns: int, status: str) -> StereoTracks:
        self.stats.status = status
        t_prev = self._ref.t_ns if self._ref is not None else t_ns
        z2 = np.zeros((0, 2))
        return StereoTracks(
            t_prev_ns=int(t_prev), t_ns=int(t_ns), track_id=np.zeros(0, np.int64),
            uv_left_prev=z2, uv_right_prev=z2, uv_left=z2, uv_right=z2, p_Ckm1_F=np.zeros((0, 3)),
            inlier=np.zeros(0, bool), egomotion=None,
        )

    # ------------------------------------------------------------------ main entry
    def process(
        self, t_ns: int, img_left_raw: object, img_right_raw: object,
        motion_prior: Egomotion | None = None,
    ) -> StereoTracks | None:
        """Process one raw stereo pair taken at ``t_ns``.

        Returns ``None`` until a first good frame has been seen; afterwards ``StereoTracks`` of
        the features seen at the reference frame and now (egomotion ``None`` if no measurement).
        ``motion_prior`` (e.g. IMU-predicted ``T_Ck_Ckm1`` with covariance) rejects estimates that
        contradict it (e.g. all features on a moving object). Never raises on bad images.
        """
        o = self.options
        tm: dict[str, float] = {}
        t0 = time.perf_counter()
        self._watch_stereo(self.stats.status)
        self.stats = FrameStats(t_ns=int(t_ns), timings_ms=tm)
        shape = (self.rig.height, self.rig.width)
        if self._exchange:
            img_left_raw, img_right_raw = img_right_raw, img_left_raw
        gl, gr = as_grey(img_left_raw, shape), as_grey(img_right_raw, shape)
        if gl is None or gr is None:
            why = image_problem(img_left_raw, shape) or image_problem(img_right_raw, shape)
            if why in (None, "missing"):  # non-finite grey levels, or a frame the caller lost
                log.info("frame %d: %s image", t_ns, why or "malformed")
            else:
                # a wrong-size frame is a driver's or a calibration's mistake: say it
                self._malformed += 1
                if self._malformed <= _WARN_FIRST or self._malformed % _WARN_EVERY == 0:
                    log.warning("frame %d: stereo pair dropped (%d so far): %s", t_ns,
                                self._malformed, why)  # fmt: skip
            self.stats.status = "dropped"
            return None if self._ref is None else self._empty(t_ns, "dropped")
        # Copies: a caller may refill one buffer for every frame (a camera driver's).
        before, self._raw_before = self._raw_before, (gl.copy(), gr.copy())
        if before is not None and np.array_equal(gl, before[0]) and np.array_equal(gr, before[1]):
            # Two real exposures always differ by the sensor's noise: an exact repeat is a
            # frozen driver or a duplicated frame, whose "no motion" would contradict the IMU
            # (KITTI raw with 3 s of one pair repeated: 12 m instead of 0.28 m GPS-denied).
            self._frozen += 1
            if self._frozen == 1:
                log.warning("frame %d: the stereo pair repeats the one before to the last grey "
                            "level (a frozen camera?): dropped while it repeats", t_ns)  # fmt: skip
            self.stats.status = "frozen"
            return None if self._ref is None else self._empty(t_ns, "frozen")
        self._frozen = 0
        left, right = (gl, gr) if self._geo is not None else self.rectifier.rectify_pair(gl, gr)
        self._last_images = (left, right)
        tm["rectify"] = (time.perf_counter() - t0) * 1e3
        # Every 4th pixel in each direction: the spread of grey levels, at 1/16 of the cost.
        if texture_std(left) < o.min_texture_std or texture_std(right) < o.min_texture_std:
            log.info("frame %d: textureless (black, saturated or blank)", t_ns)
            self.stats.status = "textureless"
            return None if self._ref is None else self._empty(t_ns, "textureless")
        check = self.stereo_check
        if (not check.decided and check.pairs < CHECK_MAX_PAIRS
                and self._check_stereo(left, right, gl, gr)):  # this pair crossed, the next not
            return None if self._ref is None else self._empty(t_ns, "swapped")
        if self._swapped:
            self.stats.status = "swapped"
            return None

        t1 = time.perf_counter()
        pl, pr = Pyramid(left, o.klt), Pyramid(right, o.klt)
        disparity = None
        if o.stereo.method != "sparse":
            disparity = dense_disparity(left, right, o.stereo)
        tm["pyramid"] = (time.perf_counter() - t1) * 1e3 if disparity is None else 0.0
        if disparity is not None:
            tm["dense"] = (time.perf_counter() - t1) * 1e3

        self._frame = (int(t_ns), pl, pr, disparity)
        ref = self._ref
        result: StereoTracks | None = None
        keep_id = np.zeros(0, np.int64)
        keep_l, keep_r = np.zeros((0, 2)), np.zeros((0, 2))
        uv_l, ok_t, disp_guess = np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0)
        predicted = False
        if ref is not None:
            uv_l, ok_t, disp_guess, predicted = self._track_temporal(ref, pl, motion_prior, tm)

        # New corners are sought before the left-right match, away from the features tracked
        # now, so that one left-right KLT pass serves the tracked and the new features alike.
        # A search happens once tracks were lost, or every few frames (after a RANSAC that
        # dropped outliers the next frame sees fewer features than were kept and searches).
        self._since_detect += 1
        lost = int(ok_t.sum()) < (1.0 - o.redetect_lost_fraction) * self._n_after_detect
        search = ref is None or lost or self._since_detect >= o.redetect_every
        new_l = self._detect(left, uv_l[ok_t], tm) if search else np.zeros((0, 2))
        t3 = time.perf_counter()
        n_t = int(ok_t.sum())
        q = np.concatenate([uv_l[ok_t], new_l])
        # NaN seed: a row search starts the match of a new corner.
        seed = np.concatenate([disp_guess[ok_t], np.full(new_l.shape[0], np.nan)])
        uv_q, ok_q = (q.copy(), np.zeros(0, bool)) if q.shape[0] == 0 else self._stereo(
            pl, pr, q, seed, disparity
        )
        tm["stereo"] = (time.perf_counter() - t3) * 1e3
        new_r, ok_new = uv_q[n_t:], ok_q[n_t:]
        if search:
            if ref is not None:  # only read here: worked out on the frames that search
                flow = np.linalg.norm(uv_l[ok_t] - ref.uv_left[ok_t], axis=1)
                self._flow_px = float(np.median(flow)) if flow.size else np.inf
            if o.retry_failed_after > 0 and self._flow_px <= o.retry_max_flow_px:
                self._failed = [*self._failed, self._to_img(new_l[~ok_new])]
                self._failed = self._failed[-o.retry_failed_after :]
            else:
                self._failed = []
        new_l, new_r = new_l[ok_new], new_r[ok_new]

        if ref is not None:
            uv_r = np.zeros_like(uv_l)
            ok_s = np.zeros(uv_l.shape[0], dtype=bool)
            uv_r[ok_t], ok_s[ok_t] = uv_q[:n_t], ok_q[:n_t]
            result, keep_id, keep_l, keep_r = self._egomotion(
                t_ns, ref, uv_l, uv_r, ok_t & ok_s, motion_prior, tm
            )
            if self.stats.status == "no_consensus" and predicted and o.retry_levels > 0:
                result, keep_id, keep_l, keep_r = self._retry(t_ns, ref, pl, pr, motion_prior,
                                                              disparity, tm)  # fmt: skip
            if o.reacquire.enabled:
                result, keep_id, keep_l, keep_r = self._reacquire(
                    t_ns, ref, pl, pr, motion_prior, disparity, tm,
                    (result, keep_id, keep_l, keep_r),
                )
            if self.stats.status in HOLD_STATUSES and self._held < o.max_hold_frames:
                # Probably a transient (object filling the view): keep tracking from the last
                # trusted frame rather than adopting this one as the reference.
                self._held += 1
                tm["total"] = (time.perf_counter() - t0) * 1e3
                return result
        self._held = 0
        if search:
            self._n_after_detect = keep_l.shape[0] + new_l.shape[0]
            self._since_detect = 0
        ids = np.arange(self._next_id, self._next_id + new_l.shape[0], dtype=np.int64)
        self._next_id += new_l.shape[0]
        self.stats.new = int(new_l.shape[0])
        uv_l = np.concatenate([keep_l, new_l])
        uv_r = np.concatenate([keep_r, new_r])
        self._ref = _Reference(
            t_ns=int(t_ns), left=pl, right=pr, track_id=np.concatenate([keep_id, ids]),
            uv_left=uv_l, uv_right=uv_r, p_C_F=self.rig.triangulate(uv_l, uv_r),
        )
        tm["total"] = (time.perf_counter() - t0) * 1e3
        if result is None:
            self.stats.status = "first"
        return result

    # ------------------------------------------------------------------ keyframes
    def keyframe_features(self, t_ns: int) -> OrbStereo | None:
        """ORB features of the frame processed at ``t_ns`` with their stereo matches and
        points (``KEYFRAME_ORB_FEATURES`` at most), for a later relocalisation against it; None
        unless it is the last good frame processed."""
        f = self._frame
        if f is None or f[0] != int(t_ns):
            return None
        _, pl, pr, disparity = f
        opts = replace(self.options.reacquire, n_features=KEYFRAME_ORB_FEATURES)
        return orb_stereo(pl.image, self.rig, self._to_rect,
                          lambda uv: self._stereo(pl, pr, uv, None, disparity), opts)  # fmt: skip

    def relocalise(
        self, t_ns: int, keyframes: Sequence[tuple[int, OrbStereo]], min_inliers: int
    ) -> StereoTracks | None:
        """Tracks from a stored keyframe to the frame processed at ``t_ns``: its ORB features
        matched over the whole image to each keyframe's (``(t_ns, OrbStereo)``; Lowe's ratio,
        mutual best), left-right matched, and the RANSAC motion of the re-acquisition's
        settings; of the keyframes with a consensus of ``min_inliers`` and the front end's
        inlier fraction, the one with the most inliers. New track ids; no effect on the
        front end's own tracking. None without one."""
        f = self._frame
        if f is None or f[0] != int(t_ns) or not keyframes:
            return None
        _, pl, pr, disparity = f
        o, ro = self.options, self.options.reacquire
        uv_cur, desc_cur = self._reacquirer.current(pl.image, self._to_rect)
        ransac = replace(o.ransac, inlier_px=ro.ransac_inlier_px,
                         min_inliers=max(ro.min_inliers, min_inliers),
                         iterations=ro.ransac_iterations)  # fmt: skip
        best: StereoTracks | None = None
        for t_kf, kf in keyframes:
            i_r, i_c = match_global(kf.desc, desc_cur, ro)
            if i_r.size < max(ro.min_matches, min_inliers):
                continue
            uvl, (uvr, ok) = uv_cur[i_c], self._stereo(pl, pr, uv_cur[i_c], None, disparity)
            i_r, uvl, uvr = i_r[ok], uvl[ok], uvr[ok]
            if i_r.size < min_inliers:
                continue
            p_kf = kf.p_C_F[i_r]
            res = estimate_egomotion(p_kf, uvl, uvr, self.rig, ransac,
                                     p_cur=lambda a=uvl, b=uvr: self.rig.triangulate(a, b),
                                     rng=self._reloc_rng)  # fmt: skip
            inlier = res.inlier & self._epipolar(kf.uv_left[i_r], kf.uv_right[i_r], uvl, uvr)
            n_inl = int(inlier.sum())
            if (res.egomotion is None or n_inl < max(min_inliers, o.min_inlier_fraction * i_r.size)
                    or (best is not None and n_inl <= int(best.inlier.sum()))):  # fmt: skip
                continue
            ids = np.arange(self._next_id, self._next_id + i_r.size, dtype=np.int64)
            best = StereoTracks(
                t_prev_ns=int(t_kf), t_ns=int(t_ns), track_id=ids,
                uv_left_prev=kf.uv_left[i_r], uv_right_prev=kf.uv_right[i_r], uv_left=uvl,
                uv_right=uvr, p_Ckm1_F=p_kf, inlier=inlier, egomotion=res.egomotion,
            )  # fmt: skip
        if best is not None:
            self._next_id += best.track_id.size
            log.info("frame %d: relocalised against the keyframe of %d by descriptors, %d "
                     "inliers", t_ns, best.t_prev_ns, int(best.inlier.sum()))  # fmt: skip
        return best

    def _watch_stereo(self, status: str) -> None:
        """After ``RECHECK_AFTER`` frames in a row without a motion (``status``: the last
        frame's), look at the pairs again (``stereo_check``, at most every ``RECHECK_EVERY``
        frames): streams crossed mid-run (a driver restarted, its devices enumerated the other
        way) gave "no consensus" frame after frame and nothing else (a user's probe, KITTI raw
        with the pairs crossed from frame 13: 166 frames lost, 235 m, not a word)."""
        self._frames_seen += 1
        self._no_motion = self._no_motion + 1 if status in NO_MOTION_STATUSES else 0
        check = self.stereo_check
        # a check that decided, or gave up undecided (a dark stretch: a later swap is told)
        done = check.decided or check.pairs >= CHECK_MAX_PAIRS
        # crossed streams (no tracks) are looked at again too: a driver restarted may have
        # put them in order (a review: 50 frames lost after the order came back)
        if ((self._no_motion >= RECHECK_AFTER or self._swapped) and done
                and self._frames_seen - self._rechecked_at >= RECHECK_EVERY):  # fmt: skip
            self._rechecked_at = self._frames_seen
            if check.decided:
                self._decided_check = check
            self.stereo_check = StereoCheck(rechecks=check.rechecks + 1,
                                            exchanges=check.exchanges)  # fmt: skip

    def stereo_check_report(self) -> StereoCheck:
        """The check the report shows: the latest that decided (a recheck that did not, in a
        dark stretch, keeps the one before), with the count of rechecks."""
        check = self.stereo_check
        if check.decided or self._decided_check is None:
            return check
        return dataclasses.replace(self._decided_check, rechecks=check.rechecks)

    def _check_stereo(self, left: U8, right: U8, gl: U8, gr: U8) -> bool:
        """Pool one pair into ``stereo_check`` (rectified ``left``/``right``, or the raw ``gl``/
        ``gr`` rectified here when the front end tracks on raw images); warn once decided. True
        when a recheck found the streams crossed and exchanged them from the next pair on."""
        if self._geo is not None:
            left, right = self.rectifier.rectify_pair(gl, gr)
        check = self.stereo_check
        check.add_pair(left, right, self.options.detector)
        if not check.decided:
            return False
        problem = check.problem()
        if check.rechecks and check.swapped and not self._swapped and self._order_seen:
            # The last verdict found the streams in order, so the calibration is right and the
            # streams crossed since (a driver restarted, its devices enumerated the other way):
            # exchanged back, the run goes on (a user's probe: KITTI raw crossed from frame 13,
            # 166 frames without tracks, 235 m GPS-denied).
            self._exchange = not self._exchange
            check.exchanges += 1
            self._rechecked_at = -RECHECK_EVERY  # crossed again (a restart undone): told soon
            log.warning("stereo pair (looked at again after %d frames in a row without a "
                        "motion): %s; they were in order before, so the two streams "
                        "are exchanged back from the next pair on", RECHECK_AFTER,
                        problem)  # fmt: skip
            return True
        if check.rechecks and self._swapped:
            # crossed from the start (said then), looked at again while no tracks are given
            if not check.swapped:
                log.warning("stereo pair (looked at again): the left and right images are in "
                            "order now: tracked again%s",
                            "" if problem is None else f"; but {problem}")  # fmt: skip
        elif problem is not None:
            again = (f" (looked at again after {RECHECK_AFTER} frames in a row without a motion)"
                     if check.rechecks else "")  # fmt: skip
            log.warning("stereo pair%s: %s", again, problem)
        if check.swapped:
            self._rechecked_at = self._frames_seen  # looked at again RECHECK_EVERY frames on
        else:
            self._order_seen = True
        self._swapped = check.swapped
        return False

    def _detect(self, left: U8, uv_have: F64, tm: dict[str, float]) -> F64:
        """New corners (M, 2) rectified px away from the features ``uv_have`` (N, 2) rectified px
        and from corners that recently found no left-right match."""
        t4 = time.perf_counter()
        blocked = np.concatenate([np.zeros((0, 2)), *self._failed])
        new_l = detect_corners(left, self._to_img(uv_have), self.options.detector,
                               uv_blocked=blocked)
        if self._geo is not None:  # corners come from the raw image
            new_l = self._to_rect(new_l)
            new_l = new_l[self.rig.in_image(new_l)]
        tm["detect"] = (time.perf_counter() - t4) * 1e3
        return new_l

    def _track_temporal(
        self, ref: _Reference, pl: Pyramid, motion_prior: Egomotion | None,
        tm: dict[str, float], levels: int | None = None, use_prediction: bool = True,
    ) -> tuple[F64, NDArray[np.bool_], F64, bool]:
        """Track the reference features into this frame's left image: pixels (N, 2), validity
        (N,), the disparity (N,) px expected now (seed of the left-right match) and whether the
        KLT start was predicted from a motion."""
        o = self.options
        t2 = time.perf_counter()
        guess = None
        disp_prev = ref.uv_left[:, 0] - ref.uv_right[:, 0]
        predict = (motion_prior or self._last_motion) if use_prediction else None
        levels = o.klt.levels if levels is None else levels
        if predict is not None and ref.p_C_F.shape[0] and o.predict_tracks:
            # Constant-velocity (or prior) prediction of where features land: helps large flows.
            q = ref.p_C_F @ predict.R_Ck_Ckm1.T + predict.p_Ck_Ckm1
            uv_pred = self.rig.project(q)
            good = np.isfinite(uv_pred).all(1) & (q[:, 2] > 0.1) & self.rig.in_image(uv_pred)
            guess = np.where(good[:, None], uv_pred, ref.uv_left)
            levels = o.klt.levels_predicted
            if o.klt.adaptive_levels:
                levels = levels_for_residual(self._prior_residual_px, o.klt)
            # Predicted disparity seeds the left-right match (it grows as the camera approaches).
            with np.errstate(divide="ignore", invalid="ignore"):
                d_pred = self.rig.f * self.rig.baseline / q[:, 2]
            disp_prev = np.where(good & np.isfinite(d_pred), d_pred, disp_prev)
        guess_img = None if guess is None else self._to_img(guess)
        uv_img, ok_t = track_klt(
            ref.left, pl, self._to_img(ref.uv_left), o.klt, guess=guess_img, max_level=levels,
            fb_max_level=o.klt.fb_levels, fb_check=guess is None or o.klt.fb_when_predicted,
        )
        self._prior_residual_px = np.nan
        if guess_img is not None and ok_t.any():
            d = np.linalg.norm(uv_img[ok_t] - guess_img[ok_t], axis=1)
            k = int(0.9 * (d.size - 1))
            self._prior_residual_px = float(np.partition(d, k)[k])
        uv_l = self._to_rect(uv_img)
        ok_t &= np.isfinite(uv_l).all(1) & self.rig.in_image(uv_l)
        # A tracked feature never falls back to the row search: no finite seed, no match.
        ok_t &= np.isfinite(disp_prev) & np.isfinite(ref.p_C_F).all(1)
        tm["track"] = tm.get("track", 0.0) + (time.perf_counter() - t2) * 1e3
        return uv_l, ok_t, disp_prev, guess is not None

    def _retry(
        self, t_ns: int, ref: _Reference, pl: Pyramid, pr: Pyramid,
        motion_prior: Egomotion | None, disparity: F64 | None, tm: dict[str, float],
    ) -> tuple[StereoTracks, NDArray[np.int64], F64, F64]:
        """Second attempt after predicted tracks gave no consensus: unpredicted temporal KLT
        over ``retry_levels`` pyramid levels, left-right match, RANSAC (no prior hypothesis)."""
        o = self.options
        uv_l, ok_t, disp_guess, _ = self._track_temporal(
            ref, pl, motion_prior, tm, levels=o.retry_levels, use_prediction=False
        )
        t3 = time.perf_counter()
        uv_r = np.zeros_like(uv_l)
        ok_s = np.zeros(uv_l.shape[0], dtype=bool)
        if ok_t.any():
            uv_r[ok_t], ok_s[ok_t] = self._stereo(pl, pr, uv_l[ok_t], disp_guess[ok_t], disparity)
        tm["stereo"] = tm.get("stereo", 0.0) + (time.perf_counter() - t3) * 1e3
        self._last_motion = None
        log.info("frame %d: no consensus from predicted tracks, retried unpredicted", t_ns)
        return self._egomotion(t_ns, ref, uv_l, uv_r, ok_t & ok_s, motion_prior, tm)

    def _reacquire(
        self, t_ns: int, ref: _Reference, pl: Pyramid, pr: Pyramid,
        motion_prior: Egomotion | None, disparity: F64 | None, tm: dict[str, float],
        klt: tuple[StereoTracks, NDArray[np.int64], F64, F64],
    ) -> tuple[StereoTracks, NDArray[np.int64], F64, F64]:
        """``klt`` (the KLT result), unless KLT gave no consensus or fewer inliers than
        ``klt_min_inliers`` and descriptor matches to the reference, as new tracks, left-right
        matched, give a motion with more (``Reacquirer.two_pass``, the same RANSAC)."""
        o, st = self.options.reacquire, self.stats
        saved = (st.status, st.tracked, st.inliers, st.outliers, self._last_motion)
        # A KLT motion refused (implausible, contradicting the prior) leaves the frame as
        # unlinked as no consensus does.
        if st.status == "ok" and st.inliers >= o.klt_min_inliers:
            return klt
        ransac = replace(self.options.ransac, inlier_px=o.ransac_inlier_px,
                         min_inliers=o.min_inliers, iterations=o.ransac_iterations)  # fmt: skip
        # Matches inside the windows of the filter's predicted motion: repeated textures fill
        # the windows with wrong candidates, and the motion is checked against that prediction.
        fraction = o.min_inlier_fraction_with_prior if motion_prior is not None else None

        def attempt(m: Reacquired) -> tuple[tuple, Egomotion | None, int]:  # type: ignore[type-arg]
            ids = np.arange(self._next_id, self._next_id + m.uv_cur.shape[0], dtype=np.int64)
            self._next_id += ids.size
            new = replace(ref, track_id=ids, uv_left=m.uv_ref_left, uv_right=m.uv_ref_right,
                          p_C_F=m.p_Ckm1_F)  # fmt: skip
            uv_r, ok = self._stereo(pl, pr, m.uv_cur, None, disparity)
            got = self._egomotion(t_ns, new, m.uv_cur, uv_r, ok, motion_prior, tm, ransac,
                                  fraction)  # fmt: skip
            return (got, st.inliers, st.outliers, st.tracked), got[0].egomotion, st.inliers

        t7 = time.perf_counter()
        best = self._reacquirer.two_pass(
            ref.t_ns, ref.left.image, pl.image, self._to_rect,
            lambda uv: self._stereo(ref.left, ref.right, uv, None, None), motion_prior, attempt,
        )
        tm["reacquire"] = (time.perf_counter() - t7) * 1e3
        if best is not None and (saved[0] != "ok" or best[1] > saved[2]):
            got, st.inliers, st.outliers, st.tracked = best
            st.status, self._last_motion = "ok", got[0].egomotion
            log.info("frame %d: re-acquired by descriptors, %d inliers", t_ns, st.inliers)
            return got
        st.status, st.tracked, st.inliers, st.outliers, self._last_motion = saved
        return klt

    def _epipolar(self, uvl0: F64, uvr0: F64, uvl: F64, uvr: F64) -> NDArray[np.bool_]:
        """Features (N,) whose left and right rows agree within ``epipolar_final_px`` at both
        frames (rectified px (N, 2) each)."""
        tol = self.options.epipolar_final_px
        return (np.abs(uvl[:, 1] - uvr[:, 1]) <= tol) & (np.abs(uvl0[:, 1] - uvr0[:, 1]) <= tol)

    def _egomotion(
        self, t_ns: int, ref: _Reference, uv_l: F64, uv_r: F64, sel: NDArray[np.bool_],
        motion_prior: Egomotion | None, tm: dict[str, float],
        ransac: RansacOptions | None = None, min_fraction: float | None = None,
    ) -> tuple[StereoTracks, NDArray[np.int64], F64, F64]:
        """Egomotion from the reference features matched now (``sel``, (N,)), then the checks;
        ``ransac`` replaces the options' RANSAC settings, ``min_fraction`` their
        ``min_inlier_fraction``."""
        o = self.options
        ransac = ransac or o.ransac
        min_fraction = o.min_inlier_fraction if min_fraction is None else min_fraction
        self.stats.tracked = int(sel.sum())
        p_prev = ref.p_C_F[sel]
        uvl, uvr = uv_l[sel], uv_r[sel]
        t6 = time.perf_counter()
        prior = motion_prior or self._last_motion
        res = estimate_egomotion(
            p_prev, uvl, uvr, self.rig, ransac, p_cur=lambda: self.rig.triangulate(uvl, uvr),
            prior=prior, rng=self._rng,
        )
        tm["ransac"] = tm.get("ransac", 0.0) + (time.perf_counter() - t6) * 1e3
        epi = self._epipolar(ref.uv_left[sel], ref.uv_right[sel], uvl, uvr)
        inlier = res.inlier & epi
        ego = res.egomotion
        if o.bundle and ego is not None:
            ego, inlier = refine_or_keep(ego, inlier, ref.uv_left[sel], ref.uv_right[sel], uvl,
                                         uvr, self.rig, candidate=epi)  # fmt: skip
        status = "ok"
        n_inl = int(inlier.sum())
        if ego is None or n_inl < max(ransac.min_inliers, min_fraction * inlier.size):
            ego, status = None, "no_consensus"
        elif not plausible(ego, o):
            ego, status = None, "implausible"
        elif motion_prior is not None and not agrees_with_prior(ego, motion_prior,
                                                                o.prior_gate_chi2):
            ego, status = None, "contradicts_prior"
        if ego is None:
            inlier = np.zeros_like(inlier)
        self._last_motion = ego
        self.stats.status = status
        self.stats.inliers = int(inlier.sum())
        self.stats.outliers = int(inlier.size - inlier.sum())
        tracks = StereoTracks(
            t_prev_ns=int(ref.t_ns), t_ns=int(t_ns), track_id=ref.track_id[sel].copy(),
            uv_left_prev=ref.uv_left[sel].copy(), uv_right_prev=ref.uv_right[sel].copy(),
            uv_left=uvl, uv_right=uvr, p_Ckm1_F=p_prev, inlier=inlier, egomotion=ego,
        )
        # Carry forward: RANSAC outliers are dropped only when the motion was trusted.
        keep = inlier if ego is not None else np.ones(inlier.size, dtype=bool)
        return tracks, ref.track_id[sel][keep], uvl[keep], uvr[keep]
