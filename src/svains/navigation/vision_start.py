"""In-flight start from stereo and the IMU: gravity and velocity from the first frames' motion.

A static start needs the vehicle at rest, a GPS start needs fixes; a stereo rig launched by
hand, a car already driving or a drone already flying without GPS had neither (``svains run``
refused the moving start). Stereo gives the camera's motion in metres, so over a short window
the IMU's specific force, turned by the gyro, fixes the body's velocity and the direction of
gravity without any prior motion pattern (unlike a monocular start, which needs the
acceleration to vary to see its scale):

    p_V_Bk - p_V_B0 = v_V_B0 Δt_k + ½ g_V Δt_k² + R_V_B0 α_k

for every frame ``k`` of the window, with ``(R_V_Bk, p_V_Bk)`` the body poses stereo odometry
gives in its own frame V and ``α_k = ∫∫ R_B0_B(τ) f_B(τ) dτ²`` the specific force turned by
the gyro (bias first fitted to the odometry's rotations) and integrated twice. Six unknowns
(``v_V_B0``, ``g_V``), three equations per frame, linear least squares; ``|g_V|`` is then set to
gravity's magnitude and the velocity refitted. The fitted magnitude before that is the check:
odometry or IMU that disagree (a wrong baseline, a wrong mount, a window the front end could
not follow) fit another gravity and the start is refused.

The world frame is V turned so that ``g_V`` points along ``gravity_W``, about the axis between
them (its yaw is the odometry's first camera's: a gauge, as after a static start).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.errors import InitialisationError
from svains.frontend.vo_chain import chain_egomotion
from svains.geometry.rotation import so3_exp, so3_log

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
BIAS_ITERATIONS = 4  # body turning 0.75 rad in the window: the bias to 1e-5 rad/s


@dataclass(frozen=True)
class VisionInertialFit:
    """What the window gave, at its first frame ``t0_ns``: ``R_W_V`` (3, 3) turning the
    odometry's frame onto the world's, the body's velocity ``v_V`` (3,) m/s and gravity
    ``g_V`` (3,) m/s² in V, the gyro bias ``b_g`` (3,) rad/s, standard deviations of the
    velocity ``v_std`` (3,) m/s and of the tilt ``tilt_std`` rad (least squares, scaled by the
    fit's residual), the residual ``rms_m`` m, the gravity magnitude fitted freely
    ``g_fit_mps2``, the ``frames`` used and the ``span_s`` (s) they cover."""

    t0_ns: int
    R_W_V: F64
    v_V: F64
    g_V: F64
    b_g: F64
    v_std: F64
    tilt_std: float
    rms_m: float
    g_fit_mps2: float
    frames: int
    span_s: float = 0.0


def _rotate_onto(a: F64, b: F64) -> F64:
    """The smallest rotation (3, 3) taking the direction of ``a`` onto that of ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return so3_exp(np.pi * perp / np.linalg.norm(perp))
    return so3_exp(axis / s * np.arctan2(s, c))


def _integrate(
    t_ns: I64, gyro_B: F64, accel_B: F64, t0_ns: int, at_ns: I64, b_g: F64
) -> tuple[F64, F64, F64]:
    """Turn ``R_B0_B`` (K, 3, 3), single ``β`` and double ``α`` (K, 3) integrals of the specific
    force in B0 from ``t0_ns`` to each of ``at_ns`` (K,) (non-decreasing, ≥ t0), each sample
    held until the next (the one at or before ``t0_ns`` first)."""
    grid = np.unique(np.concatenate([[t0_ns], t_ns[(t_ns > t0_ns) & (t_ns < at_ns[-1])], at_ns]))
    hold = np.clip(np.searchsorted(t_ns, grid, side="right") - 1, 0, len(t_ns) - 1)
    R = np.eye(3)
    beta = np.zeros(3)
    alpha = np.zeros(3)
    out_R, out_b, out_a = [], [], []
    k = 0
    for j in range(len(grid)):
        while k < len(at_ns) and at_ns[k] == grid[j]:
            out_R.append(R.copy())
            out_b.append(beta.copy())
            out_a.append(alpha.copy())
            k += 1
        if j + 1 == len(grid):
            break
        dt = (grid[j + 1] - grid[j]) * 1e-9
        f = R @ accel_B[hold[j]]
        alpha = alpha + beta * dt + 0.5 * f * dt * dt
        beta = beta + f * dt
        R = R @ so3_exp((gyro_B[hold[j]] - b_g) * dt)
    return np.array(out_R), np.array(out_b), np.array(out_a)


def fit_vision_inertial(
    t_frames_ns: I64, R_V_B: F64, p_V_B: F64, t_imu_ns: I64, gyro_B: F64, accel_B: F64,
    gravity_W: F64, max_g_error: float = 0.1, gyro_noise_density: float = 0.0,
    gyro_bias_std: float = np.inf, accel_noise_density: float = 0.0,
) -> VisionInertialFit:
    """Gravity, velocity and gyro bias from body poses ``R_V_B`` (K, 3, 3), ``p_V_B`` (K, 3) m
    at ``t_frames_ns`` (K,) (stereo odometry, any frame V) and the IMU in the body frame
    (``gyro_B`` rad/s, ``accel_B`` m/s², at ``t_imu_ns``); see the module docstring.
    The gyro bias the turns give is shrunk towards zero by its prior ``gyro_bias_std`` (rad/s)
    against the gyro's own noise over the window (``gyro_noise_density`` rad/s/√Hz: a noisy
    gyro's 2 s say little about its bias). The tilt's standard deviation adds to the fit's
    the IMU noise the fit cannot see (smooth over the window, it is absorbed): the gyro's
    turn walk, ``σ_g² T / 3``, and the accelerometer's mean, ``(σ_a / g)² / T`` (the paper's
    vibrating IMU over 2 s: 0.57° and 0.29°). ``InitialisationError`` with fewer than 4 frames,
    or when the gravity fitted freely is more than ``max_g_error`` (relative) from
    ``|gravity_W|``."""
    K = len(t_frames_ns)
    if K < 4:
        raise InitialisationError(f"an in-flight start from vision needs 4 frames with a motion "
                                  f"in its window, got {K}")  # fmt: skip
    t0 = int(t_frames_ns[0])
    at = np.asarray(t_frames_ns, np.int64)
    dt = (at - t0) * 1e-9
    R_B0_Bk_vo = np.einsum("ji,kjl->kil", R_V_B[0], R_V_B)
    # Gyro bias: the odometry's turns against the gyro's, first order in the bias (each turn
    # error taken as the bias times the time, a fixed-point iteration for the rest).
    b_fit = np.zeros(3)
    for _ in range(BIAS_ITERATIONS):
        R_gyro, _, _ = _integrate(t_imu_ns, gyro_B, accel_B, t0, at, b_fit)
        r = np.array([so3_log(Rg.T @ Rv) for Rg, Rv in zip(R_gyro, R_B0_Bk_vo, strict=True)])
        b_fit = b_fit - (dt[1:, None] * r[1:]).sum(axis=0) / float(dt[1:] @ dt[1:])
    var_fit = gyro_noise_density**2 / dt[-1]  # white rate noise averaged over the window
    var_prior = gyro_bias_std**2
    b_g = b_fit if not np.isfinite(var_prior) else b_fit * var_prior / (var_prior + var_fit)
    _, _, alpha = _integrate(t_imu_ns, gyro_B, accel_B, t0, at, b_g)
    rhs = (p_V_B[1:] - p_V_B[0] - alpha[1:] @ R_V_B[0].T).reshape(-1)
    eye = np.eye(3)
    A = np.concatenate([np.hstack([d * eye, 0.5 * d * d * eye]) for d in dt[1:]])
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    g_fit = sol[3:]
    g_norm = float(np.linalg.norm(gravity_W))
    g_fit_norm = float(np.linalg.norm(g_fit))
    if not abs(g_fit_norm / g_norm - 1.0) <= max_g_error:
        raise InitialisationError(
            f"in-flight start from vision: the first {dt[-1]:.1f} s of stereo motion and IMU fit "
            f"a gravity of {g_fit_norm:.3g} m/s² ({g_norm:.3g} expected): odometry and IMU "
            "disagree (the camera-IMU calibration, the stereo baseline, or frames the front end "
            "could not follow); try a longer init.vision_window_s or --init groundtruth"
        )
    g_V = g_fit * (g_norm / g_fit_norm)
    # The velocity again with gravity's magnitude known.
    A_v = A[:, :3]
    v_V, *_ = np.linalg.lstsq(A_v, rhs - A[:, 3:] @ g_V, rcond=None)
    resid = rhs - A_v @ v_V - A[:, 3:] @ g_V
    dof = max(len(rhs) - 6, 1)
    sigma2 = float(resid @ resid) / dof
    cov = sigma2 * np.linalg.inv(A.T @ A)
    # Tilt: the component of g's error across g, over its magnitude.
    u = g_V / g_norm
    across = np.eye(3) - np.outer(u, u)
    T = float(dt[-1])
    tilt_var = (float(np.trace(across @ cov[3:, 3:] @ across) / 2.0) / g_norm**2
                + gyro_noise_density**2 * T / 3.0 + (accel_noise_density / g_norm) ** 2 / T)
    tilt_std = float(np.sqrt(tilt_var))
    return VisionInertialFit(
        t0_ns=t0, R_W_V=_rotate_onto(g_V, np.asarray(gravity_W, float)), v_V=v_V, g_V=g_V,
        b_g=b_g, v_std=np.sqrt(np.diag(cov[:3, :3])), tilt_std=tilt_std,
        rms_m=float(np.sqrt(np.mean(resid**2))), g_fit_mps2=g_fit_norm, frames=K,
        span_s=float(dt[-1]),
    )


def state_at(
    fit: VisionInertialFit, R_V_B0: F64, t_imu_ns: I64, gyro_B: F64, accel_B: F64, t_ns: int
) -> tuple[F64, F64]:
    """Attitude ``R_W_B`` (3, 3) and velocity ``v_W_B`` (3,) m/s at ``t_ns`` (≥ the window's
    first frame), carried from it by the IMU (position: the caller's origin)."""
    R, beta, _ = _integrate(t_imu_ns, gyro_B, accel_B, fit.t0_ns, np.array([t_ns], np.int64),
                            fit.b_g)  # fmt: skip
    dt = (t_ns - fit.t0_ns) * 1e-9
    v_V = fit.v_V + fit.g_V * dt + R_V_B0 @ beta[0]
    return fit.R_W_V @ R_V_B0 @ R[0], fit.R_W_V @ v_V


class StartOdometry:
    """Stereo odometry over the first frames for ``init.mode: vision``: its own tracks source
    (the ``vo`` method's: egomotion of every frame, bundle-adjusted), chained into the left
    camera's poses in its first frame V. A frame without a motion, or not the successor of the
    last one, starts the chain anew from it (the window must be one unbroken chain)."""

    def __init__(self, cam0: Any, cam1: Any, max_row_diff_px: float | None) -> None:
        self._cams = (cam0, cam1)
        self._max_row_diff_px = max_row_diff_px
        self._source: Any = None
        self.t_ns: list[int] = []
        self.T_V_C: list[F64] = []

    def add_frame(self, t_ns: int, payload: tuple) -> None:
        """One frame as the Navigator stages it: ``("images", left, right)`` or
        ``("features", track_id, uv_left, uv_right)``."""
        from svains.navigation.tracks import TrackOptions
        from svains.navigation.vision_sources import (
            FeatureFrames,
            ImageFrames,
            rig_from_calibrations,
        )

        kind = payload[0]
        if self._source is None:
            if kind == "images":
                self._source = ImageFrames(*self._cams, bundle=True)
            else:
                opts = TrackOptions(max_row_diff_px=self._max_row_diff_px, egomotion=True,
                                    bundle=True)  # fmt: skip
                self._source = FeatureFrames(rig_from_calibrations(*self._cams), opts)
        if self._source.kind != kind:
            return
        # Its own copies: the tracks source the filter is fed the same arrays.
        self._source.push(int(t_ns), *(np.array(a, copy=True) for a in payload[1:]))
        tr = self._source.tracks_at(int(t_ns))
        linked = (tr is not None and tr.egomotion is not None and bool(self.t_ns)
                  and int(tr.t_prev_ns) == self.t_ns[-1])  # fmt: skip
        if not linked:
            self.t_ns, self.T_V_C = [int(t_ns)], [np.eye(4)]
            return
        self.t_ns.append(int(t_ns))
        self.T_V_C.append(chain_egomotion([tr.egomotion], self.T_V_C[-1])[-1])  # type: ignore[union-attr]

    def span_s(self) -> float:
        return (self.t_ns[-1] - self.t_ns[0]) * 1e-9 if self.t_ns else 0.0

    def body_poses(self) -> tuple[I64, F64, F64]:
        """Frame times (K,), body attitudes ``R_V_B`` (K, 3, 3) and positions ``p_V_B`` (K, 3)
        (through the rectified left camera's mount on the body)."""
        rig = self._source.rig
        R_B_C, p_B_C = np.asarray(rig.R_B_C, float), np.asarray(rig.p_B_C, float)
        T = np.array(self.T_V_C)
        R_V_B = T[:, :3, :3] @ R_B_C.T
        p_V_B = T[:, :3, 3] - R_V_B @ p_B_C
        return np.array(self.t_ns, np.int64), R_V_B, p_V_B
