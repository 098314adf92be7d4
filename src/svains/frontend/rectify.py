"""Stereo rectification: two raw calibrated cameras -> one ideal pinhole pair (``RectifiedStereo``).

OpenCV's ``stereoRectify`` rotates both cameras about their optical centres so that epipolar lines
become image rows (zero-disparity flag: both principal points equal). ``R1`` maps raw left-camera
components to rectified ones, ``p_Crect = R1 p_C0``, so the rectified left camera sits on the body
with ``R_B_Crect = R_B_C0 R1^T`` and the same optical centre ``p_B_C0``.

Lens models (``svains.geometry.distortion``): radial-tangential with 4 or 5 coefficients (OpenCV
takes either) and equidistant fisheye (``cv2.fisheye`` maps and point undistortion; the
rectified pinhole pair is chosen as in ``_rectifying_projections``).

Already-rectified input (KITTI, the simulator: no distortion, equal intrinsics and orientation,
baseline along x) is recognised and passed through untouched, so pixels stay exact.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import CalibrationError
from svains.geometry.camera import RectifiedStereo
from svains.geometry.distortion import (
    EQUIDISTANT,
    RADTAN,
    canonical_model,
    check_coefficients,
    distort,
)
from svains.sensors.types import CameraCalib

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

log = logging.getLogger(__name__)

# Tolerances for declaring a pair already rectified (rotation rad, offsets m, pixels).
_IDENT_ROT_TOL = 1e-9
_IDENT_OFFSET_TOL = 1e-9
_IDENT_PIXEL_TOL = 1e-9
# Iterative undistortion of points: run to convergence (1e-12 in normalised coordinates).
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)


def _relative_pose(cam0: CameraCalib, cam1: CameraCalib) -> tuple[F64, F64]:
    """``R_C1_C0`` (3, 3), ``p_C1_C0`` (3,) m: maps left-camera points into the right camera."""
    T_C1_C0 = np.linalg.inv(np.asarray(cam1.T_B_C, dtype=float)) @ np.asarray(cam0.T_B_C, float)
    return T_C1_C0[:3, :3], T_C1_C0[:3, 3]


def _check_calib(cam: CameraCalib) -> str:
    """The canonical distortion model of ``cam`` after checking its calibration."""
    try:
        model = canonical_model(cam.distortion_model)
        check_coefficients(model, cam.distortion)
    except CalibrationError as exc:
        raise CalibrationError(f"{cam.name}: {exc}") from exc
    if np.asarray(cam.T_B_C).shape != (4, 4):
        raise CalibrationError(f"{cam.name}: T_B_C must be 4x4")
    return model


def is_already_rectified(cam0: CameraCalib, cam1: CameraCalib) -> bool:
    """True if the pair needs no rectification: no distortion, same K and orientation, and the
    right camera offset purely along the left camera's +x axis."""
    R_C1_C0, p_C1_C0 = _relative_pose(cam0, cam1)
    return bool(
        canonical_model(cam0.distortion_model) == RADTAN
        and canonical_model(cam1.distortion_model) == RADTAN
        and np.allclose(cam0.distortion, 0.0, atol=0.0)
        and np.allclose(cam1.distortion, 0.0, atol=0.0)
        and np.allclose(cam0.K, cam1.K, atol=_IDENT_PIXEL_TOL, rtol=0.0)
        and abs(cam0.intrinsics[0] - cam0.intrinsics[1]) <= _IDENT_PIXEL_TOL
        and np.allclose(R_C1_C0, np.eye(3), atol=_IDENT_ROT_TOL, rtol=0.0)
        and np.allclose(p_C1_C0[1:], 0.0, atol=_IDENT_OFFSET_TOL)
        # Right camera at +b along x of the left one: a left point at x maps to x - b.
        and p_C1_C0[0] < 0.0
        and tuple(cam0.resolution) == tuple(cam1.resolution)
    )


def _rectifying_projections(
    cam0: CameraCalib, cam1: CameraCalib, models: tuple[str, str], size: tuple[int, int],
    alpha: float,
) -> tuple[F64, F64, F64, F64]:
    """``R1``, ``R2`` (3, 3) raw -> rectified rotations and ``P1``, ``P2`` (3, 4) projections.

    Radial-tangential pairs: ``cv2.stereoRectify`` (its ``alpha`` picks the focal length).
    Pairs with a fisheye (equidistant) camera: the rotations are the same (they depend only on
    the relative pose), and the rectified pinhole keeps the left camera's mean focal length and
    principal point at the same image size, so a pair that needs no rotation maps to the left
    camera's own pinhole (the simulator's fisheye rig rectifies to its ideal rig exactly).
    """
    R_C1_C0, p_C1_C0 = _relative_pose(cam0, cam1)
    fisheye = EQUIDISTANT in models
    d0, d1 = (np.zeros(4) if fisheye else np.asarray(c.distortion, float) for c in (cam0, cam1))
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        cam0.K, d0, cam1.K, d1, size, R_C1_C0, p_C1_C0.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha,
    )  # fmt: skip
    if fisheye:
        fu, fv, cu, cv = (float(x) for x in cam0.intrinsics)
        f = 0.5 * (fu + fv)
        baseline = float(-P2[0, 3] / P2[0, 0])
        P1 = np.array([[f, 0.0, cu, 0.0], [0.0, f, cv, 0.0], [0.0, 0.0, 1.0, 0.0]])
        P2 = P1.copy()
        P2[0, 3] = -f * baseline
    return R1, R2, P1, P2


def _float_maps(
    cam: CameraCalib, model: str, R: F64, P: F64, size: tuple[int, int]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``cv2.remap`` float maps (x, y), each (H, W), raw pixel of each rectified pixel."""
    D = np.asarray(cam.distortion, float)
    if model == EQUIDISTANT:
        mx, my = cv2.fisheye.initUndistortRectifyMap(cam.K, D, R, P, size, cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(cam.K, D, R, P, size, cv2.CV_32FC1)
    return mx, my


@dataclass(frozen=True)
class StereoRectifier:
    """Rectification of one stereo rig: the ideal pair ``rig`` plus the OpenCV maps.

    ``R1``/``R2`` (3, 3) rotate raw camera components into rectified ones; ``maps_*`` are the
    ``cv2.remap`` fixed-point maps, ``xymap_*`` (H, W, 2) float32 the raw (x, y) pixel of each
    rectified pixel; ``identity`` means input images are already rectified.
    """

    rig: RectifiedStereo
    cam0: CameraCalib | None
    cam1: CameraCalib | None
    R1: F64
    R2: F64
    P1: F64
    P2: F64
    identity: bool
    maps_left: tuple[NDArray, NDArray] | None
    maps_right: tuple[NDArray, NDArray] | None
    xymap_left: NDArray[np.float32] | None = None
    xymap_right: NDArray[np.float32] | None = None

    @classmethod
    def for_rectified_rig(cls, rig: RectifiedStereo) -> StereoRectifier:
        """Pass-through rectifier for images already rectified to ``rig`` (e.g. the simulator)."""
        P1 = np.hstack([rig.K, np.zeros((3, 1))])
        P2 = P1.copy()
        P2[0, 3] = -rig.f * rig.baseline
        return cls(rig, None, None, np.eye(3), np.eye(3), P1, P2, True, None, None)

    @classmethod
    def from_calibration(
        cls, cam0: CameraCalib, cam1: CameraCalib, alpha: float = 0.0
    ) -> StereoRectifier:
        """Rectify ``cam0`` (left) / ``cam1`` (right). ``alpha`` = 0 keeps only valid pixels
        (OpenCV's free scaling parameter), 1 keeps every source pixel."""
        m0, m1 = _check_calib(cam0), _check_calib(cam1)
        w, h = (int(v) for v in cam0.resolution)
        R_B_C0 = np.asarray(cam0.T_B_C, dtype=float)[:3, :3]
        p_B_C0 = np.asarray(cam0.T_B_C, dtype=float)[:3, 3].copy()
        _, p_C1_C0 = _relative_pose(cam0, cam1)
        if is_already_rectified(cam0, cam1):
            fu, _, cu, cv = (float(x) for x in cam0.intrinsics)
            rig = RectifiedStereo(
                f=fu, cu=cu, cv=cv, baseline=float(-p_C1_C0[0]),
                R_B_C=R_B_C0.copy(), p_B_C=p_B_C0, width=w, height=h,
            )
            P1 = np.hstack([cam0.K, np.zeros((3, 1))])
            P2 = P1.copy()
            P2[0, 3] = -fu * rig.baseline
            return cls(rig, cam0, cam1, np.eye(3), np.eye(3), P1, P2, True, None, None)

        R1, R2, P1, P2 = _rectifying_projections(cam0, cam1, (m0, m1), (w, h), alpha)
        f = float(P1[0, 0])
        baseline = float(-P2[0, 3] / P2[0, 0])
        if not np.isfinite(baseline) or baseline <= 0.0:
            p_C0_C1 = -_relative_pose(cam0, cam1)[0].T @ p_C1_C0
            raise CalibrationError(
                "stereo rectification: cam1 must be right of cam0 (along cam0's x axis), but "
                f"sits at {np.round(p_C0_C1, 4).tolist()} m in "
                "cam0's frame; cameras swapped, or T_BS given body-to-camera instead of "
                "camera-to-body?"
            )
        rig = RectifiedStereo(
            f=f, cu=float(P1[0, 2]), cv=float(P1[1, 2]), baseline=baseline,
            R_B_C=R_B_C0 @ R1.T, p_B_C=p_B_C0, width=w, height=h,
        )
        fmaps = [_float_maps(cam, m, R, P, (w, h)) for cam, m, R, P in
                 ((cam0, m0, R1, P1), (cam1, m1, R2, P2))]  # fmt: skip
        maps_left, maps_right = (cv2.convertMaps(mx, my, cv2.CV_16SC2) for mx, my in fmaps)
        xy_left, xy_right = (np.ascontiguousarray(np.stack(m, axis=-1)) for m in fmaps)
        log.debug("rectified: f=%.2f px, b=%.4f m, c=(%.1f, %.1f)", f, baseline, rig.cu, rig.cv)
        return cls(rig, cam0, cam1, R1, R2, P1, P2, False, maps_left, maps_right, xy_left,
                   xy_right)  # fmt: skip

    def rectify_left(self, img: U8) -> U8:
        """Rectified left image (same size); identity pairs are returned as they are."""
        if self.identity or self.maps_left is None:
            return img
        return cv2.remap(img, self.maps_left[0], self.maps_left[1], cv2.INTER_LINEAR)

    def rectify_right(self, img: U8) -> U8:
        """Rectified right image (same size); identity pairs are returned as they are."""
        if self.identity or self.maps_right is None:
            return img
        return cv2.remap(img, self.maps_right[0], self.maps_right[1], cv2.INTER_LINEAR)

    def rectify_pair(self, img_left: U8, img_right: U8) -> tuple[U8, U8]:
        """Both rectified images (H, W) uint8."""
        return self.rectify_left(img_left), self.rectify_right(img_right)

    def rectify_points(self, uv_raw: ArrayLike, right: bool = False) -> F64:
        """Raw (distorted) pixels (N, 2) of the left (or right) camera -> rectified (N, 2) px.

        The iterative undistortion runs to convergence (OpenCV's default 5 iterations leave up
        to 0.4 px error in the EuRoC image corners)."""
        uv = np.asarray(uv_raw, dtype=float).reshape(-1, 2)
        if self.identity or uv.shape[0] == 0:
            return uv.copy()
        cam = self.cam1 if right else self.cam0
        assert cam is not None  # only identity rectifiers lack calibrations
        R, P = (self.R2, self.P2) if right else (self.R1, self.P1)
        D = np.asarray(cam.distortion, float)
        if canonical_model(cam.distortion_model) == EQUIDISTANT:
            out = cv2.fisheye.undistortPoints(
                uv.reshape(-1, 1, 2), cam.K, D, R=R, P=P, criteria=_UNDISTORT_CRITERIA
            )
        else:
            out = cv2.undistortPoints(
                uv.reshape(-1, 1, 2), cam.K, D, R=R, P=P, criteria=_UNDISTORT_CRITERIA
            )
        return out.reshape(-1, 2).astype(float)

    def unrectify_points(self, uv_rect: ArrayLike, right: bool = False) -> F64:
        """Rectified pixels (N, 2) -> raw (distorted) pixels (N, 2) of the left (or right) camera:
        back through the rectifying rotation, then the lens model (closed form)."""
        uv = np.asarray(uv_rect, dtype=float).reshape(-1, 2)
        if self.identity or uv.shape[0] == 0:
            return uv.copy()
        cam = self.cam1 if right else self.cam0
        assert cam is not None
        R, P = (self.R2, self.P2) if right else (self.R1, self.P1)
        ray = np.stack(
            [(uv[:, 0] - P[0, 2]) / P[0, 0], (uv[:, 1] - P[1, 2]) / P[1, 1], np.ones(len(uv))],
            axis=1,
        ) @ R  # rows R^T ray: rectified -> raw camera axes
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = ray[:, 0] / ray[:, 2], ray[:, 1] / ray[:, 2]
        xd = distort(np.stack([x, y], axis=1), cam.distortion_model, cam.distortion)
        # Rays behind the raw camera have no image.
        xd[~(ray[:, 2] > 0.0)] = np.nan
        K = cam.K
        return np.stack(
            [K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]],
            axis=1,
        )

    def sample_rectified(
        self, img: U8, rows: NDArray[np.int64], cols: NDArray[np.int64], right: bool = False
    ) -> NDArray[np.float32]:
        """Grey levels of the rectified image at integer rectified pixels (``rows``, ``cols``
        broadcast together, inside the image), read from the *input* image ``img``: bilinear
        samples at the raw positions, i.e. what a full ``cv2.remap`` would give there, for the
        cost of the few pixels needed. Identity rigs index ``img`` directly."""
        xy = self.xymap_right if right else self.xymap_left
        if self.identity or xy is None:
            return img[rows, cols].astype(np.float32)
        flat = rows * xy.shape[1] + cols  # broadcast (..., n) flat pixel indices
        # One gather of 8-byte (x, y) pairs, then one remap of just these pixels.
        pairs = np.take(xy.view(np.complex64).reshape(-1), flat)
        m = pairs.view(np.float32).reshape(-1, flat.shape[-1], 2)
        out = cv2.remap(img, m, None, cv2.INTER_LINEAR)
        return out.reshape(flat.shape).astype(np.float32)
