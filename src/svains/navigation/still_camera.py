"""The camera's witness of a rest: how fast it can have moved over the last ``window_s``.

The IMU's rest test (``navigation.zupt.StaticTest``) cannot tell a rest from a steady motion:
a robot driving straight at 0.8 m/s passed it on most of its 0.5 s windows, and with
``zupt.after_start`` the filter met hundreds of "v = 0" updates while driving (a user's probe).
A camera that moves sees its features move, by ``f t / Z`` for a translation ``t`` and a
feature at depth ``Z``. ``StillCamera`` keeps the left pixels and stereo disparities of each
frame's tracks over the last ``window_s``; between the frames at both ends of that span it fits
the camera's small translation and rotation to the displacements of the features seen at both
(the linearised flow of a calibrated camera, least squares with the pixels' noise; positions
and inverse depths from both frames' mean, whose noise is uncorrelated with the displacement:
the first frame's alone read a resting camera's newest pair as moving 56 % of the time, its
noise in both the displacement and the depth) and returns a bound on the speed: the
translation's norm plus three of its standard deviations, over the span. A near scene bounds
the speed tightly, a far one loosely; the caller takes the rest as a zero velocity only under
its limit, and as uncertain as the bound (a median pixel motion under 1.5 px, the first
witness, called a village drone creeping at 0.05-0.2 m/s still, and those zeros were fused:
a review).

Only the tracks the front end kept as inliers enter, a fit whose residuals the pixels' noise
does not explain (something in view moves with the camera: a hood, a car ahead) tells
nothing, and the newest frame pair must show no significant translation of its own: the
span's average lags a pull-away (a review: 0.05 m/s fused as rest 0.2 s into one).
"""

from __future__ import annotations

import collections

import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import StereoTracks
from svains.geometry.camera import RectifiedStereo

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

# px: features nearer the infinite than this disparity carry no depth
MIN_DISPARITY_PX = 0.5
# the fit's misfit per degree of freedom beyond which it tells nothing: a resting camera's
# reads about 1 (the village stops, 0.5 px features); twelve features riding with a camera
# that drives at 0.5 m/s among fifty still ones read far beyond (tests/test_still_camera.py)
MAX_MISFIT = 4.0
# a normal matrix this ill-conditioned (scene, geometry) gives no usable translation
MAX_COND = 1e12
# the newest pair's translation moves when t^T cov^-1 t exceeds this (chi-square, 3 dof, 0.99)
MOVED_CHI2 = 11.34
# The start's rest ends when the span's translation is this significant (chi-square, 3 dof,
# 1e-4) at this many frames running: at 16 simulated static starts and EuRoC's the largest was
# 17.8 (a probe), a creep the IMU's limits pass crosses it within 1-2 s.
START_MOVED_CHI2 = 21.11
START_MOVED_FRAMES = 3


class StillCamera:
    """A bound on the camera's speed over the last ``window_s`` (see the module docstring):
    ``observe`` each frame's tracks, ask ``speed_bound`` at a time."""

    def __init__(self, rig: RectifiedStereo, pixel_std_px: float, window_s: float,
                 min_features: int = 10) -> None:  # fmt: skip
        self.rig = rig
        self.pixel_std_px = float(pixel_std_px)
        self.window_ns = int(window_s * 1e9)
        self.min_features = int(min_features)
        # (t_ns, sorted track ids, their left pixels (M, 2), inverse depths (M,) 1/m, NaN where
        # the disparity is too small) of the recent frames
        self._frames: collections.deque[tuple[int, I64, F64, F64]] = collections.deque()
        # the start's rest: frames running whose span moved, and the newest one counted
        self._moved_run = 0
        self._moved_frame_ns: int | None = None

    def observe(self, tr: StereoTracks | None) -> None:
        """The tracks ending at a frame (None: a frame without tracks, which ends the span)."""
        if tr is None or tr.track_id.size == 0:
            self._frames.clear()
            return
        ids = np.asarray(tr.track_id)
        order = np.argsort(ids, kind="stable")
        order = order[np.asarray(tr.inlier, bool)[order]]
        uv_l = np.asarray(tr.uv_left, float)[order]
        disparity = uv_l[:, 0] - np.asarray(tr.uv_right, float)[order, 0]
        with np.errstate(divide="ignore"):
            inv_depth = np.where(disparity > MIN_DISPARITY_PX,
                                 disparity / (self.rig.f * self.rig.baseline), np.nan)  # fmt: skip
        self._frames.append((int(tr.t_ns), ids[order], uv_l, inv_depth))
        # keep the newest frame at least ``window_ns`` before the latest, not older ones
        while len(self._frames) > 2 and self._frames[-1][0] - self._frames[1][0] >= self.window_ns:
            self._frames.popleft()

    @property
    def last_frame_ns(self) -> int | None:
        """The stamp of the newest frame observed (None: none in the span)."""
        return self._frames[-1][0] if self._frames else None

    def speed_bound(self, t_ns: int) -> float | None:
        """How fast (m/s) the camera can have moved over the span of at least ``window_s``
        that ends at its latest frame: the fitted translation's norm plus 3 standard deviations,
        over the span (inf when the newest frame pair moved); None when it cannot tell (no
        frame within ``window_s`` before ``t_ns``, no span that long, fewer than
        ``min_features`` inliers with a depth seen at both ends, a degenerate fit, or one the
        pixels' noise does not explain)."""
        m = self._span_motion(t_ns, newest=True)
        if m is None:
            return None
        bound, _, newest_chi2 = m
        return float("inf") if newest_chi2 > MOVED_CHI2 else bound  # its average lags

    def start_rest_std(self, t_ns: int, velocity_std_mps: float) -> float | None:
        """The camera's word on the START's rest at ``t_ns``, which the IMU's test passed: inf
        once the span's translation has been significant (``START_MOVED_CHI2``) at
        ``START_MOVED_FRAMES`` frames running (a creep the IMU's limits pass: the zeros held a
        vehicle setting off over 12 s at rest, velocity NEES 25), the zero's standard deviation
        loosened to the speed bound where the span moved at 0.99 only, None where it says
        nothing (as ``speed_bound``, or no motion)."""
        m = self._span_motion(t_ns)
        if m is None:
            self._moved_run = 0
            return None
        bound, chi2, _ = m
        frame_ns = self._frames[-1][0]
        if frame_ns != self._moved_frame_ns:  # each frame counts once
            self._moved_frame_ns = frame_ns
            self._moved_run = self._moved_run + 1 if chi2 > START_MOVED_CHI2 else 0
        if self._moved_run >= START_MOVED_FRAMES:
            return float("inf")
        return max(velocity_std_mps, bound) if chi2 > MOVED_CHI2 else None

    def _span_motion(self, t_ns: int, newest: bool = False) -> tuple[float, float, float] | None:
        """The speed bound (m/s) over the span ``speed_bound`` reads, the span translation's
        chi-square against rest and, with ``newest``, the newest frame pair's (0 where it has
        no fit or is not asked for); None where the camera cannot tell (``speed_bound``'s
        cases)."""
        if len(self._frames) < 2:
            return None
        last = self._frames[-1]
        if t_ns - last[0] > self.window_ns:
            return None
        first = next((f for f in reversed(self._frames) if last[0] - f[0] >= self.window_ns), None)
        got = None if first is None else self._fit(first, last)
        if got is None:
            return None
        p_C0_C1, cov_p = got  # the camera's displacement over the span, in its own axes
        pair = self._fit(self._frames[-2], last) if newest else None
        newest_chi2 = 0.0 if pair is None else _chi2(*pair)
        sigma = float(np.sqrt(max(np.linalg.eigvalsh(cov_p)[-1], 0.0)))
        bound = (float(np.linalg.norm(p_C0_C1)) + 3.0 * sigma) / ((last[0] - first[0]) * 1e-9)
        return bound, _chi2(p_C0_C1, cov_p), newest_chi2

    def _fit(self, first: tuple[int, I64, F64, F64],
             last: tuple[int, I64, F64, F64]) -> tuple[F64, F64] | None:  # fmt: skip
        """The camera's translation (3,) m between the frames ``first`` and ``last`` and its
        covariance (3, 3), from the inliers with a depth seen at both (None: too few, a
        degenerate fit, or a misfit beyond ``MAX_MISFIT``)."""
        _, ids_last, uv_last, iz_last = last
        _, ids_first, uv_first, iz_first = first
        _, i_last, i_first = np.intersect1d(ids_last, ids_first, return_indices=True)
        iz = 0.5 * (iz_first[i_first] + iz_last[i_last])
        near = np.isfinite(iz)
        if int(near.sum()) < self.min_features:
            return None
        i_last, i_first = i_last[near], i_first[near]
        return _fit_motion(self.rig, uv_first[i_first], uv_last[i_last], iz[near],
                           np.sqrt(2.0) * self.pixel_std_px)  # fmt: skip


def _chi2(p: F64, cov: F64) -> float:
    """``p^T cov^-1 p``: a translation (3,) against rest, in its covariance's units."""
    return float(p @ np.linalg.solve(cov, p))


def _fit_motion(rig: RectifiedStereo, uv0: F64, uv1: F64, iz: F64,
                std_px: float) -> tuple[F64, F64] | None:  # fmt: skip
    """Least-squares small camera motion from the displacements ``uv1 - uv0`` (M, 2) px of
    features at inverse depth ``iz`` (M,) 1/m, seen about the mean of ``uv0`` and ``uv1``: the
    flow ``f (A t / Z + B ω)`` of a translation ``t`` (m) and rotation ``ω`` (rad) in the
    camera's axes, each displacement's noise ``std_px``. Returns ``t`` (3,) and its covariance
    (3, 3) m², None when the normal matrix is singular or the residuals exceed ``MAX_MISFIT``
    times their noise per degree of freedom."""
    mid = 0.5 * (uv0 + uv1)
    x = (mid[:, 0] - rig.cu) / rig.f
    y = (mid[:, 1] - rig.cv) / rig.f
    zero = np.zeros_like(x)
    # rows: the u and v flow per feature; columns: t (3), ω (3)
    Hu = np.stack([-iz, zero, x * iz, x * y, -(1.0 + x * x), y], axis=1)
    Hv = np.stack([zero, -iz, y * iz, 1.0 + y * y, -x * y, -x], axis=1)
    H = rig.f * np.concatenate([Hu, Hv])
    d = np.concatenate([uv1[:, 0] - uv0[:, 0], uv1[:, 1] - uv0[:, 1]])
    N = H.T @ H
    if not np.all(np.isfinite(N)) or np.linalg.cond(N) > MAX_COND:
        return None
    L = np.linalg.cholesky(N)
    motion = np.linalg.solve(L.T, np.linalg.solve(L, H.T @ d))
    r = d - H @ motion
    if float(r @ r) / std_px**2 > MAX_MISFIT * max(d.size - 6, 1):
        return None
    # the translation's block of N⁻¹, from the factor: (L⁻¹ E)ᵀ (L⁻¹ E), E its three columns
    W = np.linalg.solve(L, np.eye(6)[:, :3])
    return motion[:3], std_px**2 * (W.T @ W)
