"""Stereo tracks between consecutive frames of pre-tracked features (``features0``).

A frame of features is one row per track: track id and rectified left/right pixels.
``TrackBuilder`` pairs each frame with the previous one into ``svains.frontend.types.StereoTracks``
(the same type the image front end produces), one frame at a time, so the vision updaters do not
care where tracks came from. ``tracks_from_features`` does it for a whole recorded stream.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.errors import DatasetError
from svains.frontend.types import Egomotion, StereoTracks
from svains.geometry.camera import RectifiedStereo

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackOptions:
    """How recorded features become tracks.

    ``max_row_diff_px``: stereo epipolar gate ``|v_left - v_right|`` at both frames (``None`` = no
    gate); ``min_disparity_px``: smallest disparity at k-1 (eq. 10 depth must be finite);
    ``egomotion``: run the front end's RANSAC + Gauss-Newton egomotion on each frame pair (needed
    by ``lc``/``vo``; its inlier mask then replaces the all-true default); ``bundle``: refine it
    with the points on all four pixels of every feature that passed the gates
    (``frontend.egomotion_bundle``; its inliers replace RANSAC's; off, the RANSAC estimate);
    ``bundle_max_gap_s``: refine it also, with ``bundle`` off, when the frames are at most
    that many seconds apart (None: never); ``widen``: where RANSAC finds no motion, retry at
    wider inlier thresholds
    (``frontend.egomotion.estimate_egomotion_widening``: frames seconds apart). For ``lc``,
    whose filter gates the motion against the IMU's prediction; not for ``vo``, which would
    chain a wrong wide consensus unchecked (tracks gone wrong can agree on a wrong motion
    within 20 px: KLT tracks of a synthetic textured plane moved 80 px between two frames
    gave a majority on a wrong motion in 2 of 4 seeds).
    """

    max_row_diff_px: float | None = 2.0
    min_disparity_px: float = 0.5
    egomotion: bool = False
    bundle: bool = False
    bundle_max_gap_s: float | None = None
    widen: bool = False

    def refine(self, gap_s: float) -> bool:
        """Whether the egomotion of frames ``gap_s`` s apart is refined by the bundle."""
        return self.bundle or (self.bundle_max_gap_s is not None
                               and gap_s <= self.bundle_max_gap_s)  # fmt: skip


def frame_slices(fs: Any) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Distinct frame times (F,) and start offsets (F+1,) of their rows (rows sorted by time)."""
    t = np.asarray(fs.t_ns, dtype=np.int64)
    if t.size and np.any(np.diff(t) < 0):
        raise DatasetError("features0 rows are not sorted by timestamp")
    times, starts = np.unique(t, return_index=True)
    return times, np.append(starts, t.size)


def _estimate(
    p_prev: F64, uv_left: F64, uv_right: F64, rig: RectifiedStereo, p_cur: F64, seed: int,
    prior: Egomotion | None, prev_pixels: tuple[F64, F64, NDArray[np.bool_]] | None = None,
    widen: bool = False,
) -> tuple[Egomotion | None, NDArray[np.bool_]]:
    """The front end's egomotion and inliers (``widen``: retried at wider inlier thresholds
    where it finds none); with ``prev_pixels`` (the k-1 left and right pixels and which
    features passed the gates), refined by the two-frame bundle adjustment
    (``frontend.egomotion_bundle``), which keeps the RANSAC result when it fails."""
    # Imported lazily: the front end's egomotion is only needed by lc/vo.
    from svains.frontend.egomotion import (
        RansacOptions,
        estimate_egomotion,
        estimate_egomotion_widening,
    )

    estimate = estimate_egomotion_widening if widen else estimate_egomotion
    res = estimate(
        p_prev, uv_left, uv_right, rig, RansacOptions(seed=seed), p_cur=p_cur, prior=prior
    )
    if res.egomotion is None or prev_pixels is None:
        return res.egomotion, res.inlier
    from svains.frontend.egomotion_bundle import refine_or_keep

    uvl0, uvr0, candidate = prev_pixels
    return refine_or_keep(res.egomotion, res.inlier, uvl0, uvr0, uv_left, uv_right, rig,
                          candidate=candidate)  # fmt: skip


# One frame of features: time (ns), track ids (M,), rectified left and right pixels (M, 2).
Frame = tuple[int, NDArray[np.int64], F64, F64]


def pair_frames(
    prev: Frame, cur: Frame, rig: RectifiedStereo, options: TrackOptions
) -> StereoTracks:
    """The tracks from frame ``prev`` to frame ``cur`` (any two frames: their shared ids),
    ``p_Ckm1_F`` triangulated at ``prev`` (eq. 10), ``inlier`` the disparity and epipolar
    gates of ``options``; no egomotion."""
    t_a, ids_a, uvl_a, uvr_a = prev
    t_b, ids, uvl_b, uvr_b = cur
    _, ia, ib = np.intersect1d(ids_a, ids, assume_unique=False, return_indices=True)
    uvl0, uvr0 = uvl_a[ia], uvr_a[ia]
    uvl1, uvr1 = uvl_b[ib], uvr_b[ib]
    p_prev = rig.triangulate(uvl0, uvr0)
    ok = np.isfinite(p_prev).all(axis=1) & (uvl0[:, 0] - uvr0[:, 0] >= options.min_disparity_px)
    ok &= np.isfinite(uvl1).all(axis=1) & np.isfinite(uvr1).all(axis=1)
    if options.max_row_diff_px is not None:
        ok &= np.abs(uvl0[:, 1] - uvr0[:, 1]) <= options.max_row_diff_px
        ok &= np.abs(uvl1[:, 1] - uvr1[:, 1]) <= options.max_row_diff_px
    return StereoTracks(
        t_prev_ns=int(t_a), t_ns=int(t_b), track_id=ids_a[ia],
        uv_left_prev=uvl0, uv_right_prev=uvr0, uv_left=uvl1, uv_right=uvr1,
        p_Ckm1_F=p_prev, inlier=ok, egomotion=None,
    )  # fmt: skip


class TrackBuilder:
    """Pairs each new frame of features with the previous one (see ``add``).

    Tracks are matched by id between frame k-1 and k; ``p_Ckm1_F`` is triangulated at k-1
    (eq. 10). ``inlier`` is all-true except features failing the disparity/epipolar gates (or,
    with ``options.egomotion``, the RANSAC outliers, seeded with the frame counter and chained
    with the previous egomotion as prior); ``egomotion`` is ``None`` unless requested.
    """

    def __init__(self, rig: RectifiedStereo, options: TrackOptions | None = None) -> None:
        self.rig = rig
        self.options = options or TrackOptions()
        self._prev: Frame | None = None
        self._k = 0  # frames seen so far
        self._prior: Egomotion | None = None

    @property
    def last(self) -> Frame | None:
        """The last frame added (None before the first)."""
        return self._prev

    def add(
        self, t_ns: int, track_id: NDArray[np.int64], uv_left: F64, uv_right: F64
    ) -> StereoTracks | None:
        """Tracks from the previous frame to this one (``None`` for the first frame).
        ``track_id`` (M,), ``uv_left``/``uv_right`` (M, 2) rectified px."""
        ids = np.asarray(track_id, dtype=np.int64)
        uvl_b, uvr_b = np.asarray(uv_left, dtype=float), np.asarray(uv_right, dtype=float)
        prev, self._prev = self._prev, (int(t_ns), ids, uvl_b, uvr_b)
        k = self._k
        self._k += 1
        if prev is None:
            return None
        tr = pair_frames(prev, self._prev, self.rig, self.options)
        opts, rig, ok = self.options, self.rig, tr.inlier
        uvl0, uvr0, uvl1, uvr1, p_prev = (tr.uv_left_prev, tr.uv_right_prev, tr.uv_left,
                                          tr.uv_right, tr.p_Ckm1_F)  # fmt: skip
        ego: Egomotion | None = None
        if opts.egomotion and ok.sum() >= 3:
            p_cur = rig.triangulate(uvl1, uvr1)
            ego, inl = _estimate(p_prev, uvl1, uvr1, rig, p_cur, seed=k, prior=self._prior,
                                 prev_pixels=(uvl0, uvr0, ok)
                                 if opts.refine((tr.t_ns - tr.t_prev_ns) * 1e-9) else None,
                                 widen=opts.widen)
            ok &= inl
            self._prior = ego
        return replace(tr, inlier=ok, egomotion=ego)


def tracks_from_features(
    fs: Any, rig: RectifiedStereo, options: TrackOptions | None = None
) -> list[StereoTracks]:
    """One ``StereoTracks`` per consecutive frame pair (F-1 of them, possibly with M = 0) of a
    recorded stream ``fs`` (a ``FeatureStream``: rows ``t_ns``, ``track_id``, ``uv_left``,
    ``uv_right``, sorted by time), see ``TrackBuilder``."""
    times, bounds = frame_slices(fs)
    builder = TrackBuilder(rig, options)
    out: list[StereoTracks] = []
    for k in range(len(times)):
        rows = slice(bounds[k], bounds[k + 1])
        tr = builder.add(int(times[k]), fs.track_id[rows], fs.uv_left[rows], fs.uv_right[rows])
        if tr is not None:
            out.append(tr)
    log.debug("built %d stereo track sets from %d frames", len(out), len(times))
    return out
