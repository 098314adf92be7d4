"""Relocalisation against stored keyframes, for a frame that lost its link to the frame before.

A frame that shares too few features with the frame before (a long gap, a fast turn, the view
blocked) leaves the IMU alone to carry the state until the next linked frame, and the drift of
that stretch stays in every later pose: the clones of the pixel models measure motion, never
where the rig is. A platform that comes back to a place it has seen (a MAV in a room, a
survey's return leg) sees features of a frame taken long before. ``KeyframeMemory`` stores,
at most every ``keyframe_spacing_s``, a fused frame's features with the filter's pose
estimate and its 6x6 covariance at that frame. For a frame with no link, the source finds
the stored frame it can be matched with, and the updater fuses the frame against it as
against a clone (``CloneWindow.add_keyframe``; ``tc``/``3d`` its pixels, ``lc`` its
egomotion), the stored pose added to the state for that one update (``Relocaliser``):

- recorded features whose ids persist (``features0``, an external front end with its own
  place recognition): the keyframe that shares the most ids (``most_shared``);
- the image front end, whose ids do not survive a lost track: the keyframes whose camera
  looked the same way from nearby at their stored poses (``by_view``), tried by ORB
  descriptors over the whole image and RANSAC (``StereoFrontend.relocalise``).

The stored pose's error is correlated with the state's (the state grew out of it), and the
filter no longer holds that correlation. Taken as independent, the pose makes the update
overconfident unless the drift since it is large against its own uncertainty. For a scalar
with keyframe variance ``a``, the state's ``r·a`` (its error the keyframe's plus an
independent drift) and the keyframe's variance inflated to ``c·a``, the update's reported
variance covers its true one exactly when ``c (r - 2) >= r``: never for ``r <= 2``, ``c = 5``
at ``r = 2.5``, ``c → 1`` for a large drift. ``keyframe_covariance`` applies this per block
(position, attitude; ``r`` from the traces): a block whose ratio is below
``relocalise_min_drift`` (2.5) is fused ``WEAK_INFLATION`` (25) times wider, which keeps the
update within a few percent of consistent for any ratio (roll and pitch, held by gravity, drift
little), and without the position block the frame is not relocalised. The same test keeps a
keyframe from being used again before the state has drifted from it as far again.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from svains.errors import FilterError
from svains.geometry.rotation import quat_exp, quat_multiply, quat_normalize, quat_to_rotmat
from svains.models.state import DP, DTH
from svains.models.state import P as P_SLICE
from svains.models.state import Q as Q_SLICE
from svains.navigation.tracks import Frame

if TYPE_CHECKING:
    from svains.filter.ukf import UpdateStats
    from svains.frontend.types import StereoTracks
    from svains.geometry.camera import RectifiedStereo
    from svains.navigation.base import FrameContext
    from svains.navigation.options import VisionOptions
    from svains.navigation.vision_clones import CloneWindow

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)

POSE_ROWS = np.r_[DP, DTH]  # the pose's (δp, δθ_B) rows of the tangent


# A block whose drift ratio is below the threshold is fused this many times wider: the update
# then barely uses it and stays within 4 % of consistent for any ratio (a factor that removed
# the block altogether would spread the sigma points' attitudes over radians).
WEAK_INFLATION = 25.0


def keyframe_covariance(
    P_kf: F64, P_now: F64, min_ratio: float, min_inflation: float
) -> F64 | None:
    """The keyframe pose covariance (6, 6; ``(δp, δθ_B)``) to fuse it with as independent of
    the state, whose pose covariance is ``P_now`` (6, 6): each block (position, attitude)
    scaled by ``max(min_inflation, r / (r - 2))`` with ``r`` the ratio of the traces now / at
    the keyframe, or by ``WEAK_INFLATION`` when ``r < min_ratio``; None when the position
    block is (nothing to gain: the state has not drifted from the keyframe)."""
    scale = np.empty(6)
    for rows in (slice(0, 3), slice(3, 6)):
        a = float(np.trace(P_kf[rows, rows]))
        r = float(np.trace(P_now[rows, rows])) / a if a > 0 else np.inf
        if r < min_ratio and rows.start == 0:
            return None
        scale[rows] = max(min_inflation, r / (r - 2.0)) if r >= min_ratio else WEAK_INFLATION
    d = np.sqrt(scale)
    return P_kf * np.outer(d, d)


@dataclass(frozen=True)
class Keyframe:
    """A stored frame at ``t_ns``: what its source needs to match it again (``features``:
    recorded features' ``Frame``, the image front end's ``OrbStereo``), the body pose estimate
    at it (``p_W_B`` (3,) m, ``q_W_B_wxyz`` (4,)) and that pose's covariance ``P_pose`` (6, 6;
    tangent ``(δp, δθ_B)``, m and rad)."""

    t_ns: int
    features: Any
    p_W_B: F64
    q_W_B_wxyz: F64
    P_pose: F64

    @property
    def position_variance(self) -> float:
        """Trace of the position block (m²)."""
        return float(np.trace(self.P_pose[:3, :3]))

    @property
    def nbytes(self) -> int:
        f = self.features
        held = f.nbytes if hasattr(f, "nbytes") else sum(a.nbytes for a in f[1:])
        return int(held) + self.P_pose.nbytes + self.p_W_B.nbytes + self.q_W_B_wxyz.nbytes


class KeyframeMemory:
    """Keyframes at least ``spacing_s`` apart, at most ``max_keyframes``: when full, every
    other one is dropped and the spacing doubles, so a long run keeps frames from all of it."""

    def __init__(self, spacing_s: float, max_keyframes: int) -> None:
        self.spacing_ns = int(spacing_s * 1e9)
        self.max_keyframes = int(max_keyframes)
        self.keyframes: list[Keyframe] = []

    def due(self, t_ns: int) -> bool:
        """Whether a frame at ``t_ns`` would be stored (``spacing_s`` after the last one)."""
        return not self.keyframes or int(t_ns) - self.keyframes[-1].t_ns >= self.spacing_ns

    def remember(self, t_ns: int, features: Any, x: F64, P: F64) -> bool:
        """Store the frame at ``t_ns`` (its ``features``) with the pose of the navigation state
        ``x`` (nx,) and its covariance from ``P`` (ndx, ndx) when it is ``due``."""
        if not self.due(t_ns):
            return False
        P_pose = np.asarray(P, dtype=float)[np.ix_(POSE_ROWS, POSE_ROWS)].copy()
        self.keyframes.append(Keyframe(int(t_ns), features, np.array(x[P_SLICE], float),
                                       np.array(x[Q_SLICE], float), P_pose))  # fmt: skip
        if len(self.keyframes) > self.max_keyframes:
            self.keyframes = self.keyframes[::2]
            self.spacing_ns *= 2
        return True

    def shift(self, dp_W: F64) -> None:
        """Move every stored pose by ``dp_W`` (3,) m: the world itself moved (a local start's
        height taken from the sonar, ``navigation.sonar_anchor``)."""
        self.keyframes = [replace(k, p_W_B=k.p_W_B + dp_W) for k in self.keyframes]

    def turn(self, theta_W: F64, pivot_W: F64) -> None:
        """Turn every stored pose by the rotation vector ``theta_W`` (3,) rad about
        ``pivot_W`` (3,) m: the world frame turned (a local start's heading found from the GPS,
        ``navigation.heading_wait``). The pose covariances (position turned with it) keep
        their size; the turn's own uncertainty is the state's."""
        q_z_wxyz = quat_exp(theta_W)
        R_z = quat_to_rotmat(q_z_wxyz)
        pivot = np.asarray(pivot_W, dtype=float)
        J = np.eye(6)
        J[:3, :3] = R_z
        self.keyframes = [
            replace(k, p_W_B=pivot + R_z @ (k.p_W_B - pivot),
                    q_W_B_wxyz=quat_normalize(quat_multiply(q_z_wxyz, k.q_W_B_wxyz)),
                    P_pose=J @ k.P_pose @ J.T)
            for k in self.keyframes
        ]  # fmt: skip

    @property
    def n_bytes(self) -> int:
        """Memory held by the stored features and poses (bytes)."""
        return sum(k.nbytes for k in self.keyframes)


def most_shared(
    keyframes: Sequence[Keyframe], frame: Frame, min_shared: int
) -> tuple[Keyframe, int] | None:
    """Of ``keyframes`` holding recorded features (``Frame``), the one that shares the most
    track ids with ``frame``, and that count; among those that share at least half as many,
    the one with the smallest position variance. None when none shares ``min_shared``."""
    ids = np.unique(np.asarray(frame[1]))
    cands = [(k, int(np.isin(k.features[1], ids).sum())) for k in keyframes]
    if not cands:
        return None
    most = max(n for _, n in cands)
    if most < min_shared:
        return None
    good = [(k, n) for k, n in cands if n >= max(min_shared, most // 2)]
    return min(good, key=lambda kn: kn[0].position_variance)


def by_view(
    keyframes: Sequence[Keyframe], x: F64, R_B_C: F64, p_B_C: F64, max_angle_deg: float,
    max_distance_m: float,
) -> list[Keyframe]:
    """``keyframes`` whose left camera, at its stored pose, looked within ``max_angle_deg`` of
    the camera at the navigation state ``x`` and stood within ``max_distance_m`` of it, the
    closest views first (angle over 30° plus distance over 2 m): where a place seen before is
    sought without ids (descriptors over the whole image)."""
    def camera(p_W_B: F64, q_wxyz: F64) -> tuple[F64, F64]:
        R_W_B = quat_to_rotmat(np.asarray(q_wxyz, float))
        return p_W_B + R_W_B @ p_B_C, R_W_B @ R_B_C[:, 2]

    c_now, z_now = camera(np.asarray(x[P_SLICE], float), np.asarray(x[Q_SLICE], float))
    scored = []
    for k in keyframes:
        c, z = camera(k.p_W_B, k.q_W_B_wxyz)
        angle = float(np.degrees(np.arccos(np.clip(z @ z_now, -1.0, 1.0))))
        dist = float(np.linalg.norm(c - c_now))
        if angle <= max_angle_deg and dist <= max_distance_m:
            scored.append((angle / 30.0 + dist / 2.0, k))
    return [k for _, k in sorted(scored, key=lambda sk: sk[0])]


# Keyframes sought by view for the image front end (``by_view``): cameras that looked within
# this angle (deg), from within this distance (m) plus 3 position sigmas of the state.
RELOCALISE_MAX_ANGLE_DEG = 60.0
RELOCALISE_MIN_REACH_M = 3.0


class Relocaliser:
    """One vision updater's keyframes (``remember`` after each frame) and the relocalisation
    of a frame that lost its link (``attempt``), against the clones of ``clones`` and the
    frames of ``source`` (``FeatureFrames`` or ``ImageFrames``: ``keyframe_features``,
    ``relocalisation_tracks``) of the rig ``rig``."""

    def __init__(self, options: VisionOptions, clones: CloneWindow, source: Any,
                 rig: RectifiedStereo) -> None:  # fmt: skip
        self.options = options
        self.clones = clones
        self.source = source
        self.rig = rig
        self.memory = KeyframeMemory(options.keyframe_spacing_s, options.max_keyframes)
        self.relocalised = 0

    def remember(self, ctx: FrameContext, fused: bool) -> None:
        """Store the frame at ``ctx.t_ns`` (posterior state) when it was ``fused`` and is due."""
        if fused and self.memory.due(ctx.t_ns):
            features = self.source.keyframe_features(ctx.t_ns)
            if features is not None:
                self.memory.remember(ctx.t_ns, features, ctx.ukf.x, ctx.ukf.P)

    def _find(self, ctx: FrameContext) -> tuple[Keyframe, StereoTracks, F64] | None:
        """A keyframe the source matches the frame at ``ctx.t_ns`` with, its tracks, and the
        covariance to fuse its pose with (``keyframe_covariance``); None without one."""
        o, ukf = self.options, ctx.ukf
        P_now = ukf.P[np.ix_(POSE_ROWS, POSE_ROWS)]
        P_fused: dict[int, F64] = {}  # keyframe time -> the covariance to fuse its pose with
        for k in self.memory.keyframes:
            if k.t_ns < ctx.t_ns and (P := keyframe_covariance(
                    k.P_pose, P_now, o.relocalise_min_drift, o.relocalise_inflation)) is not None:
                P_fused[k.t_ns] = P
        usable = [k for k in self.memory.keyframes if k.t_ns in P_fused]
        drift = float(np.trace(ukf.P[DP, DP]))
        if not usable:
            log.debug("t=%.3f s: no relocalisation, the state's position variance %.3g m² is "
                      "not %g times any keyframe's", ctx.t_ns * 1e-9, drift,
                      o.relocalise_min_drift)  # fmt: skip
            return None
        if getattr(self.source, "kind", None) == "images":
            # No ids to say which keyframe saw this place: those that looked the same way
            # from nearby, at the poses the filter gives (the closest first).
            reach = RELOCALISE_MIN_REACH_M + 3.0 * np.sqrt(drift)
            usable = by_view(usable, ukf.x, self.rig.R_B_C, self.rig.p_B_C,
                             RELOCALISE_MAX_ANGLE_DEG, reach)  # fmt: skip
        found = self.source.relocalisation_tracks(ctx.t_ns, usable, o.relocalise_min_features)
        if found is None:
            return None
        kf, tr = found
        return kf, tr, P_fused[kf.t_ns]

    def attempt(
        self, ctx: FrameContext, fuse: Callable[[StereoTracks], UpdateStats | None]
    ) -> UpdateStats | None:
        """Put a matching keyframe's pose in the state (``CloneWindow.add_keyframe``) and
        ``fuse`` the tracks from it; None when none matches. A numerical failure of that
        update drops the keyframe and skips it (the state is as before; raised if the update
        had changed it). Counted in ``relocalised`` when accepted."""
        found = self._find(ctx)
        if found is None:
            return None
        kf, tr, P_kf = found
        ukf = ctx.ukf
        x0, P0 = ukf.x.copy(), ukf.P.copy()
        std_before = float(np.sqrt(np.trace(ukf.P[DP, DP])))
        self.clones.add_keyframe(ukf, kf.t_ns, kf.p_W_B, kf.q_W_B_wxyz, P_kf)
        try:
            stats = fuse(tr)
        except (np.linalg.LinAlgError, FilterError) as exc:
            # The keyframe is independent of the state: without it the state is as it was,
            # unless the update had changed it (then the failure is the filter's own).
            self.clones.drop(ukf, kf.t_ns)
            if not (np.array_equal(ukf.x, x0) and np.array_equal(ukf.P, P0)):
                raise
            log.warning("t=%.3f s: the relocalisation against the keyframe of t=%.3f s failed "
                        "numerically and is skipped (%s)", ctx.t_ns * 1e-9, kf.t_ns * 1e-9, exc)
            return None
        if stats is not None and stats.accepted:
            self.relocalised += 1
            log.info("t=%.3f s: relocalised against the keyframe of t=%.3f s (%d shared "
                     "features, position std %.3g m before)", ctx.t_ns * 1e-9, kf.t_ns * 1e-9,
                     int(tr.inlier.sum()), std_before)  # fmt: skip
        return stats

    def summary(self) -> dict[str, Any]:
        """``report.json`` keys: ``frames_relocalised``, ``keyframes_stored``, ``keyframes_kb``."""
        return {"frames_relocalised": self.relocalised,
                "keyframes_stored": len(self.memory.keyframes),
                "keyframes_kb": round(self.memory.n_bytes / 1024, 1)}  # fmt: skip
