"""Re-acquisition by descriptors where KLT cannot bridge two frames (long gaps, low frame rates,
fast turns).

ORB features (FAST corners, oriented BRIEF, OpenCV) are detected in the reference left image and
in the current one. Reference features are matched left to right in the reference pair and
triangulated; then each is matched to a current feature by Hamming distance:

- with a motion prior ``T_Ck_Ckm1`` and its covariance (the filter's IMU-propagated pose): only
  inside its search window, the ellipse where the prior puts the point (the motion covariance
  and the depth uncertainty mapped to pixels, ``gate_chi2``), best of the window with a ratio
  test against the window's second best;
- without one: over the whole image, Lowe's ratio test and a mutual best-match check.

The matches then go through the front end's own left-right match and RANSAC, as KLT tracks do.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]
T = TypeVar("T")


@dataclass(frozen=True)
class ReacquireOptions:
    """``enabled``: try descriptors when KLT gave no consensus; ``n_features`` ORB features per
    image (FAST threshold ``fast_threshold``); ``ratio`` Lowe's ratio over the whole image,
    ``window_ratio`` inside a prior's window; ``max_hamming`` bits of 256; ``gate_chi2`` of the
    window (2 dof, 99.9 %); ``pixel_std`` px added to the predicted pixel spread (feature
    position, lens); ``disparity_std`` px of the reference disparity (depth uncertainty);
    ``min_matches`` to attempt an egomotion; ``ransac_inlier_px`` the RANSAC inlier limit of
    the re-acquired matches (KITTI raw at 1 Hz, 5-8 m steps: the reference depth errors move a
    far point's reprojection by several px, and 1.5 px kept 27 % of mostly good matches, 4 px
    77 %, with the motion error unchanged) and ``min_inliers`` its consensus (with 8, a 2.8 s
    gap through a swerve gave a motion 6° off from 8 matches of distant background); the first
    motion found guides a second pass (windows, ``guided_prior``); ``klt_min_inliers``: a KLT
    motion with fewer inliers is checked against re-acquisition too (over long gaps a few KLT
    tracks can agree on a wrong motion; a refused KLT motion is re-acquired like no consensus);
    ``min_inlier_fraction_with_prior`` replaces the front
    end's ``min_inlier_fraction`` for matches made inside a motion prior's windows (rendered
    keyframes 2.3 s and 37° apart, the village's repeated bricks and tiles: 38 of 216 windowed
    matches agree on the motion within 0.7° and 0.11 m of 2.96 m, refused at 0.3);
    ``ransac_iterations`` the RANSAC hypotheses on those matches (at a quarter of inliers 50
    draws miss every all-inlier triple one time in three; 500 find more true motions across
    gaps of seconds and more wrong ones on repeated texture: measured, not the default, see
    the low-rate results page)."""

    enabled: bool = True
    n_features: int = 2000
    fast_threshold: int = 10
    ratio: float = 0.8
    window_ratio: float = 0.9
    max_hamming: int = 64
    gate_chi2: float = 13.8
    pixel_std: float = 3.0
    disparity_std: float = 0.5
    min_matches: int = 8
    ransac_inlier_px: float = 4.0
    min_inliers: int = 12
    guided_inflation: float = 25.0
    guided_min_std: tuple[float, float] = (5e-3, 0.1)
    klt_min_inliers: int = 30
    min_inlier_fraction_with_prior: float = 0.15
    ransac_iterations: int = 50


@dataclass(frozen=True)
class Reacquired:
    """Matches across the gap (K of them), rectified px: reference left/right ``uv_ref_*``
    (K, 2), reference points ``p_Ckm1_F`` (K, 3) m, current left ``uv_cur`` (K, 2)."""

    uv_ref_left: F64
    uv_ref_right: F64
    p_Ckm1_F: F64
    uv_cur: F64


def orb_features(img: U8, opts: ReacquireOptions) -> tuple[F64, U8]:
    """ORB features of a grey image: pixels (N, 2) of the image given, descriptors (N, 32)."""
    orb = cv2.ORB_create(nfeatures=opts.n_features, fastThreshold=opts.fast_threshold)
    kps, desc = orb.detectAndCompute(img, None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    return np.array([k.pt for k in kps], dtype=float), desc


def predict_pixels(
    rig: RectifiedStereo, p_Ckm1_F: F64, prior: Egomotion, opts: ReacquireOptions
) -> tuple[F64, F64, Bool]:
    """Where the prior puts reference points ``p_Ckm1_F`` (N, 3) m in the current left image:
    pixels (N, 2), their covariance (N, 2, 2) px² and validity (N,) (in front of the camera).

    ``p_Ck = R p + t`` with ``R = R̂ Exp(δθ)``, ``t = t̂ + δt`` (``prior.cov`` over (δθ, δt)):
    ``∂p_Ck/∂δθ = -R̂ [p]×``, ``∂p_Ck/∂δt = I``; the depth spread of a stereo point adds
    ``σ_z = z² σ_d / (f b)`` along its ray."""
    p = np.asarray(p_Ckm1_F, float)
    R = prior.R_Ck_Ckm1
    q = p @ R.T + prior.p_Ck_Ckm1
    z = q[:, 2]
    valid = z > 0.1
    zs = np.where(valid, z, 1.0)
    uv = rig.project(np.column_stack([q[:, :2], zs]))
    f = rig.f
    J_proj = np.zeros((p.shape[0], 2, 3))
    J_proj[:, 0, 0] = J_proj[:, 1, 1] = f / zs
    J_proj[:, 0, 2] = -f * q[:, 0] / zs**2
    J_proj[:, 1, 2] = -f * q[:, 1] / zs**2
    skew = np.zeros((p.shape[0], 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
    skew = skew - np.swapaxes(skew, 1, 2)
    J_motion = np.concatenate([-R @ skew, np.broadcast_to(np.eye(3), skew.shape)], axis=2)
    J = J_proj @ J_motion  # (N, 2, 6)
    cov = J @ prior.cov @ np.swapaxes(J, 1, 2)
    # Depth: δp = (p / z_prev) δz_prev, σ_z = z_prev² σ_d / (f b).
    z_prev = np.where(p[:, 2] > 1e-6, p[:, 2], 1e-6)
    sz = z_prev**2 * opts.disparity_std / (f * rig.baseline)
    ray = J_proj @ (R @ (p / z_prev[:, None]).T).T[:, :, None]  # (N, 2, 1)
    cov += (sz**2)[:, None, None] * (ray @ np.swapaxes(ray, 1, 2))
    cov += opts.pixel_std**2 * np.eye(2)
    return uv, cov, valid & np.isfinite(uv).all(1)


def match_in_windows(
    uv_pred: F64, cov_px: F64, desc_ref: U8, uv_cur: F64, desc_cur: U8, opts: ReacquireOptions
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Indices (i_ref, i_cur) of window matches: for each predicted reference pixel (N, 2) with
    covariance (N, 2, 2), the best current feature (M of them) inside its gate."""
    if uv_pred.shape[0] == 0 or uv_cur.shape[0] == 0:
        e = np.zeros(0, np.int64)
        return e, e
    d = uv_cur[None, :, :] - uv_pred[:, None, :]  # (N, M, 2)
    S_inv = np.linalg.inv(cov_px)
    m2 = np.einsum("nmi,nij,nmj->nm", d, S_inv, d)
    gate = (m2 <= opts.gate_chi2).astype(np.uint8)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = bf.knnMatch(desc_ref, desc_cur, k=2, mask=gate)
    return _accept(knn, opts.window_ratio, opts.max_hamming)


def match_global(
    desc_ref: U8, desc_cur: U8, opts: ReacquireOptions
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Indices (i_ref, i_cur) of whole-image matches: ratio test and mutual best match."""
    if desc_ref.shape[0] < 2 or desc_cur.shape[0] < 2:
        e = np.zeros(0, np.int64)
        return e, e
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    i_ref, i_cur = _accept(bf.knnMatch(desc_ref, desc_cur, k=2), opts.ratio, opts.max_hamming)
    back = bf.match(desc_cur, desc_ref)
    best_ref = np.full(desc_cur.shape[0], -1, np.int64)
    for m in back:
        best_ref[m.queryIdx] = m.trainIdx
    mutual = best_ref[i_cur] == i_ref
    return i_ref[mutual], i_cur[mutual]


def _accept(knn: list, ratio: float, max_hamming: int) -> tuple[NDArray[np.int64], NDArray[
    np.int64
]]:
    """Matches whose best distance passes ``max_hamming`` and the ratio test (a lone candidate
    passes the ratio test), one per current feature (the closest)."""
    best: dict[int, tuple[int, float]] = {}
    for pair in knn:
        if not pair:
            continue
        m = pair[0]
        if m.distance > max_hamming or (len(pair) > 1 and m.distance > ratio * pair[1].distance):
            continue
        if m.trainIdx not in best or m.distance < best[m.trainIdx][1]:
            best[m.trainIdx] = (m.queryIdx, m.distance)
    i_cur = np.fromiter(best.keys(), np.int64, len(best))
    i_ref = np.fromiter((v[0] for v in best.values()), np.int64, len(best))
    return i_ref, i_cur


@dataclass(frozen=True)
class OrbStereo:
    """A frame's ORB features with a stereo match (K of them): rectified left and right pixels
    (K, 2), points ``p_C_F`` (K, 3) m in its left camera, descriptors (K, 32)."""

    uv_left: F64
    uv_right: F64
    p_C_F: F64
    desc: U8

    @property
    def nbytes(self) -> int:
        return self.uv_left.nbytes + self.uv_right.nbytes + self.p_C_F.nbytes + self.desc.nbytes


def orb_stereo(
    img: U8, rig: RectifiedStereo, to_rect: Callable[[F64], F64],
    stereo: Callable[[F64], tuple[F64, Bool]], opts: ReacquireOptions,
) -> OrbStereo:
    """ORB features of the left image ``img`` (the tracked one, raw or rectified) inside the
    rectified view that ``stereo`` (rectified px -> right px, found) matches, triangulated
    (``to_rect`` maps ``img``'s pixels to rectified ones)."""
    uv_img, desc = orb_features(img, opts)
    uv = to_rect(uv_img)
    ok = np.isfinite(uv).all(1) & rig.in_image(uv)
    uv_r, ok_s = stereo(uv[ok]) if ok.any() else (np.zeros((0, 2)), np.zeros(0, bool))
    p = rig.triangulate(uv[ok][ok_s], uv_r[ok_s])
    good = np.isfinite(p).all(1) & (p[:, 2] > 0.1)
    return OrbStereo(uv[ok][ok_s][good], uv_r[ok_s][good], p[good], desc[ok][ok_s][good])


class Reacquirer:
    """Descriptor matching between a reference stereo frame and the current left image; the
    reference's ORB features, stereo matches and points are kept while it stays the reference."""

    def __init__(self, rig: RectifiedStereo, options: ReacquireOptions) -> None:
        self.rig = rig
        self.options = options
        self._ref_t_ns: int | None = None
        self._ref: tuple[F64, F64, F64, U8] | None = None

    def _reference(
        self, t_ns: int, img: U8, to_rect: Callable[[F64], F64],
        stereo: Callable[[F64], tuple[F64, Bool]],
    ) -> tuple[F64, F64, F64, U8]:
        """Reference features with a stereo match: left, right (rectified px), points, desc."""
        if self._ref_t_ns != t_ns or self._ref is None:
            f = orb_stereo(img, self.rig, to_rect, stereo, self.options)
            self._ref = (f.uv_left, f.uv_right, f.p_C_F, f.desc)
            self._ref_t_ns = t_ns
        return self._ref

    def current(self, img: U8, to_rect: Callable[[F64], F64]) -> tuple[F64, U8]:
        """ORB features of the current left image inside the rectified view: rectified px
        (M, 2), descriptors (M, 32)."""
        uv_img, desc = orb_features(img, self.options)
        uv = to_rect(uv_img)
        ok = np.isfinite(uv).all(1) & self.rig.in_image(uv)
        return uv[ok], desc[ok]

    def match(
        self, ref_t_ns: int, ref_img: U8, current: tuple[F64, U8],
        to_rect: Callable[[F64], F64], ref_stereo: Callable[[F64], tuple[F64, Bool]],
        prior: Egomotion | None,
    ) -> Reacquired | None:
        """Matches of the reference frame (image ``ref_img``, stereo matcher ``ref_stereo`` on
        rectified px) among the ``current`` features; ``to_rect`` maps image pixels to
        rectified ones. None if fewer than ``min_matches``."""
        o = self.options
        uv_l, uv_r, p, desc_ref = self._reference(ref_t_ns, ref_img, to_rect, ref_stereo)
        uv_cur, desc_cur = current
        if prior is not None:
            uv_pred, cov, valid = predict_pixels(self.rig, p, prior, o)
            i_r, i_c = match_in_windows(uv_pred[valid], cov[valid], desc_ref[valid], uv_cur,
                                        desc_cur, o)  # fmt: skip
            i_r = np.flatnonzero(valid)[i_r]
        else:
            i_r, i_c = match_global(desc_ref, desc_cur, o)
        if i_r.size < o.min_matches:
            return None
        return Reacquired(uv_l[i_r], uv_r[i_r], p[i_r], uv_cur[i_c])

    def two_pass(
        self, ref_t_ns: int, ref_img: U8, cur_img: U8, to_rect: Callable[[F64], F64],
        ref_stereo: Callable[[F64], tuple[F64, Bool]], prior: Egomotion | None,
        attempt: Callable[[Reacquired], tuple[T, Egomotion | None, int]],
    ) -> T | None:
        """Match (``prior``'s windows, else the whole image) and ``attempt`` a motion from the
        matches (-> result, motion or None, inliers); a motion found guides a second, windowed
        pass (``guided_prior``). The result with more inliers, None without a motion."""
        current = self.current(cur_img, to_rect)
        best: tuple[T, int] | None = None
        for _ in range(2):
            m = self.match(ref_t_ns, ref_img, current, to_rect, ref_stereo, prior)
            if m is None:
                break
            result, ego, n_inliers = attempt(m)
            if ego is None:
                break
            if best is None or n_inliers > best[1]:
                best = (result, n_inliers)
            prior = guided_prior(ego, self.options)
        return None if best is None else best[0]


def guided_prior(ego: Egomotion, opts: ReacquireOptions) -> Egomotion:
    """A first descriptor-matched motion as the prior of a guided second pass: its covariance
    times ``guided_inflation``, floored at ``guided_min_std`` (rad, m) per axis."""
    cov = opts.guided_inflation * np.asarray(ego.cov, float)
    floor = np.repeat(np.asarray(opts.guided_min_std, float) ** 2, 3)
    cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
    return Egomotion(R_Ck_Ckm1=ego.R_Ck_Ckm1, p_Ck_Ckm1=ego.p_Ck_Ckm1, cov=cov)
