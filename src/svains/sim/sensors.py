"""Sensor models of the simulator: IMU, GPS, magnetometer, sonar and stereo feature projections.

Noise stds are discrete per-sample values (see ``svains.sim.config``). Each function takes the
true kinematics (``TrajectorySample``) at the sensor's own timestamps and a seeded
``numpy.random.Generator``. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.camera import RectifiedStereo
from svains.sim.config import CameraConfig, GpsConfig, ImuConfig, SonarConfig
from svains.sim.trajectory import TrajectorySample
from svains.sim.world import World

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def sample_times_ns(rate_hz: float, duration_s: float, t0_ns: int = 0) -> I64:
    """Timestamps (N,) int64 ns at ``rate_hz`` covering ``[0, duration_s]``."""
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    return t0_ns + np.round(np.arange(n) * 1e9 / rate_hz).astype(np.int64)


@dataclass(frozen=True)
class ImuSamples:
    """Noisy IMU ``gyro_B``, ``accel_B`` (N, 3) and the true biases ``bg_B``, ``ba_B`` (N, 3)."""

    gyro_B: F64
    accel_B: F64
    bg_B: F64
    ba_B: F64


def simulate_imu(
    truth: TrajectorySample, g_W: ArrayLike, cfg: ImuConfig, rng: np.random.Generator
) -> ImuSamples:
    """gyro = ω_B + b_g + n_g, accel = f_B + b_a + n_a; biases follow a discrete random walk
    ``b_{k+1} = b_k + σ_rw √Δt w_k`` (σ_rw continuous density, Δt = 1/rate)."""
    n = len(truth.p_W_B)
    dt = 1.0 / cfg.rate_hz
    f_B = truth.specific_force_B(g_W)

    def walk(init: list[float], sigma: float) -> F64:
        steps = sigma * np.sqrt(dt) * rng.standard_normal((n, 3))
        steps[0] = 0.0
        return np.asarray(init, float) + np.cumsum(steps, axis=0)

    bg = walk(cfg.gyro_bias_init, cfg.gyro_random_walk)
    ba = walk(cfg.accel_bias_init, cfg.accel_random_walk)
    gyro = truth.omega_B + bg + cfg.gyro_noise_std * rng.standard_normal((n, 3))
    accel = f_B + ba + cfg.accel_noise_std * rng.standard_normal((n, 3))
    return ImuSamples(gyro, accel, bg, ba)


def gps_keep_mask(t_ns: I64, outages: list[list[float]]) -> NDArray[np.bool_]:
    """False for samples inside any ``[start_s, start_s + duration_s)`` outage."""
    t = t_ns * 1e-9
    keep = np.ones(len(t), bool)
    for start, dur in outages:
        keep &= ~((t >= start) & (t < start + dur))
    return keep


def simulate_gps(
    truth: TrajectorySample, cfg: GpsConfig, rng: np.random.Generator,
    t_ns: I64 | None = None,
) -> tuple[F64, F64]:
    """Antenna position/velocity (N, 3): ``p_G = p + R r_BG``, ``v_G = v + R (ω × r_BG)``,
    plus noise: the velocity's white, the position's white or, with
    ``cfg.position_correlation_s`` τ > 0, a first-order Gauss-Markov process of the same
    standard deviation over the fixes' times ``t_ns`` (N,) (``e_k = a e_(k-1) + √(1-a²) σ n_k``,
    ``a = exp(-Δt/τ)``: a receiver's multipath and atmosphere wander over seconds)."""
    r = np.asarray(cfg.p_B_G, float)
    p = truth.p_W_B + truth.R_W_B @ r
    v = truth.v_W_B + np.einsum("nij,nj->ni", truth.R_W_B, np.cross(truth.omega_B, r))
    n = len(p)
    e = rng.standard_normal((n, 3))
    tau = float(cfg.position_correlation_s)
    if tau > 0.0 and n > 1:
        if t_ns is None:
            raise ValueError("a correlated GPS noise needs the fixes' times t_ns")
        a = np.exp(-np.diff(np.asarray(t_ns, np.int64)) * 1e-9 / tau)
        for k in range(1, n):  # a recursion over fixes (N ~ 10^3-10^4), not a hot path
            e[k] = a[k - 1] * e[k - 1] + np.sqrt(1.0 - a[k - 1] ** 2) * e[k]
    return (
        p + cfg.position_noise_std * e,
        v + cfg.velocity_noise_std * rng.standard_normal((n, 3)),
    )


def simulate_mag(
    truth: TrajectorySample, m_W: ArrayLike, noise_std: float, rng: np.random.Generator
) -> F64:
    """Field in the body (= sensor) frame ``m_B = R^T m_W`` plus noise (N, 3) Gauss."""
    m = np.einsum("nji,j->ni", truth.R_W_B, np.asarray(m_W, float))
    return m + noise_std * rng.standard_normal(m.shape)


SONAR_R_B_S = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # sensor +z = body -z


def sonar_mount(R_W_B: F64) -> F64:
    """Sonar orientation ``R_B_S`` (3, 3): its +z along the body axis that points down most
    often along the flight (body -z for the village's x-forward/z-up body; EuRoC's IMU has x
    up, so there it is body -x)."""
    down_B = np.einsum("nji,j->i", R_W_B, [0.0, 0.0, -1.0])
    k = int(np.argmax(np.abs(down_B)))
    z = np.zeros(3)
    z[k] = np.sign(down_B[k])
    x = np.zeros(3)
    x[(k + 1) % 3] = 1.0
    return np.column_stack([x, np.cross(z, x), z])


def simulate_sonar(
    truth: TrajectorySample,
    cfg: SonarConfig,
    ground_height: float,
    rng: np.random.Generator,
    R_B_S: F64 = SONAR_R_B_S,
) -> F64:
    """Range (N,) m along the sensor's +z axis from ``p_S`` to the plane z = h (inf where the
    axis does not point down)."""
    p_S = truth.p_W_B + truth.R_W_B @ np.asarray(cfg.p_B_S, float)
    axis_W = truth.R_W_B @ R_B_S[:, 2]
    with np.errstate(divide="ignore"):
        rng_m = (ground_height - p_S[:, 2]) / axis_W[:, 2]
    rng_m = np.where(axis_W[:, 2] < -1e-6, rng_m, np.inf)
    return rng_m + cfg.noise_std * rng.standard_normal(len(rng_m))


def stereo_rig(cfg: CameraConfig, R_B_C: F64) -> RectifiedStereo:
    """The rig of ``cfg`` with left camera orientation ``R_B_C`` (3, 3)."""
    return RectifiedStereo(cfg.f, cfg.cu, cfg.cv, cfg.baseline, R_B_C,
                           np.asarray(cfg.p_B_C, float), cfg.width, cfg.height)


def camera_pose_W(rig: RectifiedStereo, R_W_B: F64, p_W_B: F64) -> tuple[F64, F64]:
    """Left camera ``R_W_C`` (3, 3) and centre ``p_W_C`` (3,) for one body pose."""
    return R_W_B @ rig.R_B_C, p_W_B + R_W_B @ rig.p_B_C


def occluded(
    origin_W: F64,
    points_W: F64,
    normals: F64,
    offsets: F64,
    eps: float = 1e-3,
    spheres: tuple[F64, F64] | None = None,
) -> NDArray[np.bool_]:
    """True where the segment ``origin → point`` (N points) passes through a solid before the
    point. Cyrus-Beck clipping of the segment against every convex solid (M solids, P planes),
    vectorised; the last ``eps`` m before the point are ignored (it lies on a face).

    ``spheres`` = (centres (M, 3), radii (M,)) enclosing the solids: only (point, solid) pairs
    whose segment comes within the sphere are clipped (a cheap exact pre-test)."""
    n_pts = len(points_W)
    hidden = np.zeros(n_pts, dtype=bool)
    if len(offsets) == 0 or n_pts == 0:
        return hidden
    d = points_W - origin_W  # (N, 3)
    length = np.linalg.norm(d, axis=1)
    t_end = 1.0 - eps / np.maximum(length, eps)
    if spheres is None:
        pi, mi = np.divmod(np.arange(n_pts * len(offsets)), len(offsets))
    else:
        centres, radii = spheres
        oc = centres - origin_W  # (M, 3)
        s = np.clip((d @ oc.T) / np.maximum(length**2, 1e-12)[:, None], 0.0, 1.0)  # (N, M)
        gap2 = (np.einsum("mk,mk->m", oc, oc)[None] - 2 * s * (d @ oc.T)
                + s**2 * (length**2)[:, None])
        pi, mi = np.nonzero(gap2 < radii[None] ** 2)
        if len(pi) == 0:
            return hidden
    nrm, off = normals[mi], offsets[mi]  # (K, P, 3), (K, P)
    num = off - nrm @ origin_W  # (K, P)
    den = np.einsum("kpj,kj->kp", nrm, d[pi])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    t_in = np.maximum(np.max(np.where(den < 0, t, -np.inf), axis=1), 0.0)
    t_out = np.minimum(np.min(np.where(den > 0, t, np.inf), axis=1), t_end[pi])
    hit = (t_in < t_out) & ~np.any((den == 0) & (num < 0), axis=1)
    hidden[pi[hit]] = True
    return hidden


def project_landmarks(
    rig: RectifiedStereo,
    R_W_C: F64,
    p_W_C: F64,
    landmarks_W: F64,
    world: World,
    t_s: float,
    max_depth: float,
) -> tuple[I64, F64, F64]:
    """Visible landmarks of one stereo frame: ids (K,), true left and right pixels (K, 2).

    Visible = in front of both cameras within ``max_depth``, inside both images, and not hidden
    by a solid as seen from either camera centre.
    """
    p_C = (landmarks_W - p_W_C) @ R_W_C  # (N, 3) = R_C_W (p_W - p_W_C)
    z = p_C[:, 2]
    ids = np.nonzero((z > 0.3) & (z < max_depth))[0]
    uv_l = rig.project(p_C[ids])
    uv_r = rig.project_right(p_C[ids])
    keep = rig.in_image(uv_l, 1.0) & rig.in_image(uv_r, 1.0)
    ids, uv_l, uv_r = ids[keep], uv_l[keep], uv_r[keep]
    if len(ids) and world.solids:
        n, d = world.planes_at(t_s)
        # only solids whose bounding sphere reaches into the viewing cone can hide anything
        centres, radii = world.bounding_spheres_at(t_s)
        c_C = (centres - p_W_C) @ R_W_C
        zc = c_C[:, 2]
        near = (zc > -radii) & (np.linalg.norm(c_C, axis=1) - radii < max_depth)
        with np.errstate(divide="ignore", invalid="ignore"):
            reach = rig.f * radii / np.maximum(zc - radii, 1e-9)
            du = np.abs(rig.f * c_C[:, 0] / zc + rig.cu - 0.5 * rig.width) - 0.5 * rig.width
            dv = np.abs(rig.f * c_C[:, 1] / zc + rig.cv - 0.5 * rig.height) - 0.5 * rig.height
        in_cone = (zc <= radii) | ((du <= reach + rig.f * rig.baseline / np.maximum(zc, 1e-9))
                                   & (dv <= reach))
        sel = near & in_cone
        n, d, sph = n[sel], d[sel], (centres[sel], radii[sel])
        p_W_C1 = p_W_C + R_W_C[:, 0] * rig.baseline
        pts = landmarks_W[ids]
        hidden = occluded(p_W_C, pts, n, d, spheres=sph)
        hidden |= occluded(p_W_C1, pts, n, d, spheres=sph)
        ids, uv_l, uv_r = ids[~hidden], uv_l[~hidden], uv_r[~hidden]
    return ids.astype(np.int64), uv_l, uv_r
