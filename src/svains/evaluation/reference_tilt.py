"""The reference trajectory's own tilt from gravity, and the rotation that levels it.

A motion-capture reference frame (EuRoC's Vicon) is set up by hand: its z axis is not exactly
against gravity (V1_01: 0.24 deg). The filter's world frame is gravity-aligned, and a ``posyaw``
alignment (yaw and translation) cannot remove a tilt, so the reference's tilt would be counted
as attitude (and velocity, position) error. This module estimates gravity in the reference's
frame ``Wr`` from the ground truth and the IMU, and the smallest rotation ``R_W_Wr`` taking it
onto the data set's ``gravity_W``.

Estimate: over the ground truth's span (and the IMU's), split into ``CHUNKS`` equal intervals
``[t_a, t_b]``, ``g_k = (v_Wr_B(t_b) − v_Wr_B(t_a) − ∫ R_Wr_B (f_B − b_a) dt) / (t_b − t_a)``
(trapezoid over the IMU samples, ``R_Wr_B`` and ``b_a`` from the ground truth, ``f_B`` the IMU
rotated by ``R_B_S``; the IMU's lever arm is neglected). ``g_Wr`` is their mean, its
uncertainty the chunks' scatter over √K. See ``docs/conventions.md`` (reference tilt).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.datasets.types import Dataset, GroundTruth, ImuStream
from svains.evaluation.alignment import rotation_about_axis
from svains.geometry.rotation import quat_rotate
from svains.replay.groundtruth import interpolate_groundtruth

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)

CHUNKS = 8  # intervals whose scatter gives the estimate's uncertainty
MIN_SPAN_S = 2.0  # shorter overlap of IMU and ground truth: no estimate
TILT_MIN_DEG = 0.05  # smaller tilts are left alone (a level reference)
TILT_MAX_DEG = 5.0  # larger ones mean mismatched data (IMU frame, biases), not a tilt
TILT_SIGMAS = 3.0  # a tilt is removed only when it is this many standard deviations
GRAVITY_NORM_TOL = 0.02  # relative |g_Wr| vs |gravity_W| mismatch beyond which nothing is removed


@dataclass(frozen=True)
class ReferenceGravity:
    """Gravity estimated in the reference's world frame: ``g_Wr`` (3,) m/s², the angle
    ``tilt_deg`` between it and ``gravity_W``, its standard deviation ``tilt_std_deg``, the
    estimate's span ``span_s`` (s), and whether the tilt is ``significant`` (``reason`` says why
    or why not)."""

    g_Wr: F64
    tilt_deg: float
    tilt_std_deg: float
    span_s: float
    significant: bool
    reason: str

    def as_report(self) -> dict[str, Any]:
        """JSON-ready dict (``report.json``'s ``reference_gravity``)."""
        return {
            "g_Wr_mps2": [float(v) for v in self.g_Wr],
            "tilt_deg": self.tilt_deg,
            "tilt_std_deg": self.tilt_std_deg,
            "span_s": self.span_s,
            "significant": self.significant,
            "reason": self.reason,
        }


def leveling_rotation(g_Wr: ArrayLike, gravity_W: ArrayLike) -> F64:
    """Smallest rotation ``R_W_Wr`` (3, 3) taking the direction of ``g_Wr`` (3,) onto that of
    ``gravity_W`` (3,): ``R_W_Wr @ g_Wr ∥ gravity_W``; identity when already parallel."""
    a = np.asarray(g_Wr, float) / np.linalg.norm(g_Wr)
    b = np.asarray(gravity_W, float) / np.linalg.norm(gravity_W)
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s < 1e-15:
        return np.eye(3)
    return rotation_about_axis(axis / s, float(np.arctan2(s, float(a @ b))))


def _chunk_gravity(gt: GroundTruth, imu: ImuStream, R_B_S: F64) -> tuple[F64, float] | None:
    """Per-chunk gravity ``g_k`` (K, 3) m/s² in the reference frame and the span (s); None
    when the IMU and the ground truth overlap less than ``MIN_SPAN_S``."""
    inside, _, v_Wr, q_Wr_B = interpolate_groundtruth(gt, imu.t_ns)
    t_ns = np.asarray(imu.t_ns)[inside]
    if t_ns.size < 2 * CHUNKS or (t_ns[-1] - t_ns[0]) * 1e-9 < MIN_SPAN_S:
        return None
    j = np.clip(np.searchsorted(gt.t_ns, t_ns), 0, len(gt.t_ns) - 1)
    ba_B = np.nan_to_num(np.asarray(gt.ba_B, float)[j], nan=0.0, posinf=0.0, neginf=0.0)
    f_B = np.asarray(imu.accel_B, float)[inside] @ R_B_S.T - ba_B
    a_Wr = quat_rotate(q_Wr_B, f_B)  # specific force in the reference frame (N, 3)
    ok = np.isfinite(a_Wr).all(axis=1) & np.isfinite(v_Wr).all(axis=1)
    t_s, a_Wr, v_Wr = (t_ns[ok] - t_ns[ok][0]) * 1e-9, a_Wr[ok], v_Wr[ok]
    if t_s.size < 2 * CHUNKS or t_s[-1] < MIN_SPAN_S:
        return None
    integral = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(0.5 * (a_Wr[1:] + a_Wr[:-1]) * np.diff(t_s)[:, None], 0)]
    )
    edges = np.searchsorted(t_s, np.linspace(0.0, t_s[-1], CHUNKS + 1))
    edges[-1] = t_s.size - 1
    a, b = edges[:-1], edges[1:]
    if np.any(b <= a):
        return None
    dt = (t_s[b] - t_s[a])[:, None]
    return (v_Wr[b] - v_Wr[a] - (integral[b] - integral[a])) / dt, float(t_s[-1])


def estimate_reference_gravity(dataset: Dataset) -> ReferenceGravity | None:
    """Gravity in the reference's world frame from its velocities and attitudes and the IMU
    (module docstring), with the tilt from ``dataset.gravity_W``; None without IMU or ground
    truth, or when they overlap less than ``MIN_SPAN_S``.

    ``significant`` when ``TILT_MIN_DEG <= tilt <= TILT_MAX_DEG``, ``tilt >= TILT_SIGMAS σ`` and
    ``|g_Wr|`` within ``GRAVITY_NORM_TOL`` of ``|gravity_W|``.
    """
    gt, imu = dataset.groundtruth, dataset.imu
    if gt is None or imu is None or len(gt.t_ns) < 2:
        return None
    R_B_S = np.eye(3) if dataset.imu_calib is None else np.asarray(dataset.imu_calib.T_B_S)[:3, :3]
    chunks = _chunk_gravity(gt, imu, R_B_S)
    if chunks is None:
        log.info("reference tilt not estimated: IMU and ground truth overlap < %g s", MIN_SPAN_S)
        return None
    g_k, span_s = chunks
    g_Wr = g_k.mean(axis=0)
    cov_g = np.cov(g_k.T) / len(g_k)  # (3, 3) m²/s⁴, of the mean
    g_W = np.asarray(dataset.gravity_W, float)
    down_W = g_W / np.linalg.norm(g_W)
    norm = float(np.linalg.norm(g_Wr))
    tilt = float(np.arctan2(np.linalg.norm(np.cross(g_Wr, down_W)), g_Wr @ down_W))
    # σ of the tilt: the scatter of g along its horizontal direction, over |g|.
    h = g_Wr - (g_Wr @ down_W) * down_W
    if np.linalg.norm(h) > 0:
        d = h / np.linalg.norm(h)
        var_h = float(d @ cov_g @ d)
    else:
        var_h = float(np.trace(cov_g) - down_W @ cov_g @ down_W) / 2.0
    tilt_deg, std_deg = float(np.degrees(tilt)), float(np.degrees(np.sqrt(max(var_h, 0.0)) / norm))
    mismatch = abs(norm / np.linalg.norm(g_W) - 1.0)
    if mismatch > GRAVITY_NORM_TOL or tilt_deg > TILT_MAX_DEG:
        reason = (f"implausible: |g_Wr| {norm:.3f} m/s² vs {np.linalg.norm(g_W):.3f}, tilt "
                  f"{tilt_deg:.2f} deg (IMU frame, biases or time offset?)")  # fmt: skip
        log.warning("reference tilt not removed: %s", reason)
        significant = False
    elif tilt_deg < TILT_MIN_DEG:
        significant, reason = False, f"level: below {TILT_MIN_DEG:g} deg"
    elif tilt_deg < TILT_SIGMAS * std_deg:
        significant, reason = False, f"undetermined: below {TILT_SIGMAS:g} sigma"
    else:
        significant, reason = True, f"above {TILT_MIN_DEG:g} deg and {TILT_SIGMAS:g} sigma"
    log.info("reference gravity %s m/s², tilt %.3f ± %.3f deg (%s)",
             np.array2string(g_Wr, precision=4), tilt_deg, std_deg, reason)  # fmt: skip
    return ReferenceGravity(g_Wr, tilt_deg, std_deg, span_s, significant, reason)
