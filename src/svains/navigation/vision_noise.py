"""Noise pieces of the pixel updates: per-feature innovation gate and IMU-increment noise."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import chi2_gate
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import skew, so3_exp
from svains.models.vision_common import ImuIncrement

F64 = NDArray[np.float64]

_EPS_ROT = 1e-6  # rad
_EPS_POS = 1e-6  # m
# Below this many σ of disparity the second difference of the depth ``f b / d`` departs from
# its second-order term by more than 3 % (``d² / (d² - σ²)``): no bias correction there.
MIN_BIAS_DISPARITY_SIGMAS = 6.0


def feature_gate(
    Y: F64, Wm: F64, Wc: F64, z: F64, R_blocks: F64, probability: float | None,
    G: F64 | None = None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_], F64]:
    """Per-feature innovation gate: (keep (M,), finite (M,), NIS (M,): inf where not finite,
    nan when ``probability`` is None and the gate is off).

    ``Y`` (S, dM) predictions of the sigma points, weights ``Wm``/``Wc`` (S,), ``z`` (dM,),
    ``R_blocks`` (M, d, d) each feature's measurement noise (d = 4 pixels, or 5 for the
    two-view model). A feature is kept when its predictions are finite and ``r^T S_m^-1 r`` (S_m
    its d x d innovation covariance, plus the block of ``G G^T`` (dM, k) when given) is below
    the chi-square(d) quantile of ``probability``.
    """
    S, n = Y.shape
    nb = R_blocks.shape[1]
    m = n // nb
    # Reductions over the long axis first: NumPy is slow reducing many short axes.
    fin_rows = np.isfinite(Y)
    finite = fin_rows.all(axis=0).reshape(m, nb).all(axis=1)
    if probability is None:
        return finite, finite, np.full(m, np.nan)
    Yf = Y if finite.all() else np.where(fin_rows, Y, 0.0)
    y = Wm @ Yf
    dY = (Yf - y).reshape(S, m, nb)
    A = dY.transpose(1, 2, 0)  # (m, d, S)
    cov = (A * Wc) @ A.transpose(0, 2, 1) + R_blocks  # batched products: faster than einsum
    if G is not None:
        Gm = G.reshape(m, nb, -1)
        cov += Gm @ Gm.transpose(0, 2, 1)
    r = (z - y).reshape(m, nb)
    # Features behind/at the camera give huge or non-finite predictions: never kept.
    ok = (
        finite
        & np.isfinite(cov.reshape(m, nb * nb)).all(axis=1)
        & (np.abs(r).max(axis=1) < 1e6)
    )
    d2 = np.full(m, np.inf)
    if ok.any():
        c, rk = (cov, r) if ok.all() else (cov[ok], r[ok])
        try:
            sol = np.linalg.solve(c, rk[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            sol = (np.linalg.pinv(c) @ rk[:, :, None])[:, :, 0]
        d2[ok] = (rk * sol) @ np.ones(nb)
    return ok & (d2 <= chi2_gate(probability, nb)), finite, d2


def increment_noise_factor(
    h_mean: Callable[[ImuIncrement], F64],
    inc: ImuIncrement,
    dt_s: float,
    gyro_noise_density: float,
    accel_noise_density: float,
) -> F64:
    """``G`` (nz, 6) with ``G G^T`` the pixel covariance caused by IMU noise in ``inc``.

    ``h_mean(inc) -> (nz,)`` predicts the pixels at the mean state. The integrated gyro noise
    rotates ``ΔR`` by ``δθ ~ N(0, σ_g² Δt I)``; the accelerometer noise moves ``J_B`` by
    ``N(0, σ_a² Δt³/3 I)`` (densities per √Hz). Columns are central differences times the std.
    """
    std_rot = gyro_noise_density * np.sqrt(dt_s)
    std_pos = accel_noise_density * np.sqrt(dt_s**3 / 3.0)
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = _EPS_ROT
        plus = h_mean(replace(inc, dR_Bkm1_Bk=inc.dR_Bkm1_Bk @ so3_exp(e)))
        minus = h_mean(replace(inc, dR_Bkm1_Bk=inc.dR_Bkm1_Bk @ so3_exp(-e)))
        cols.append((plus - minus) / (2 * _EPS_ROT) * std_rot)
    for i in range(3):
        e = np.zeros(3)
        e[i] = _EPS_POS
        plus = h_mean(replace(inc, J_B=inc.J_B + e))
        minus = h_mean(replace(inc, J_B=inc.J_B - e))
        cols.append((plus - minus) / (2 * _EPS_POS) * std_pos)
    return np.column_stack(cols)


def previous_pixel_noise(
    h_prev: Callable[[F64, F64], F64], uvl0: F64, uvr0: F64, sigma_px: float
) -> F64:
    """Per-feature noise (M, 4, 4) px² of the 4 predicted-vs-tracked numbers.

    ``σ² I`` for the tracked pixels at k plus ``σ² J J^T``, ``J`` (4, 3) the derivative of the
    prediction ``h_prev(uvl0, uvr0) -> (4M,)`` (at the mean state) w.r.t. the k-1 pixels
    ``u_left, v_left, u_right``: triangulation noise grows with depth², which the paper's constant
    pixel noise ignores. Central differences, all features at once (each feature's prediction
    depends only on its own pixels).
    """
    m = len(uvl0)
    eps = 1e-3  # px
    J = np.empty((m, 4, 3))
    for j, (which, col) in enumerate(((0, 0), (0, 1), (1, 0))):
        plus = [uvl0.copy(), uvr0.copy()]
        minus = [uvl0.copy(), uvr0.copy()]
        plus[which][:, col] += eps
        minus[which][:, col] -= eps
        J[:, :, j] = ((h_prev(*plus) - h_prev(*minus)) / (2 * eps)).reshape(m, 4)
    J = np.where(np.isfinite(J), J, 0.0)
    return sigma_px**2 * (np.eye(4) + np.einsum("mik,mjk->mij", J, J))


def previous_pixel_bias(
    h_prev: Callable[[F64, F64], F64], uvl0: F64, uvr0: F64, sigma_px: float
) -> F64:
    """Second-order bias (4M,) px of the prediction ``h_prev(uvl0, uvr0) -> (4M,)`` (at the mean
    state) made from noisy k-1 pixels: ``E[h(uv + n)] - h(uv) = ½ σ² Σ_j ∂²h/∂u_j²`` over the k-1
    pixels that enter it (``u_left, v_left, u_right``), by central second differences with step
    σ (exact for the quadratic term). Subtracting it from the prediction leaves an innovation
    with zero mean to second order.

    Why: the depth ``f b / d`` and the reprojection at k are convex in the k-1 disparity, so a
    prediction from noisy pixels overshoots the feature's flow on average and the filter reads
    the excess as motion. It is a small part of a larger bias: on the simulated village (3d,
    0.5 px, 8 seeds) the along-track speed comes out low on every seed, 0.50 % without this
    correction, 0.46 % with it (0.18 % at 0.05 px: the rest scales with the pixel noise too,
    first order in the noise, not removed here). Non-finite
    entries are 0, and so is the bias of features whose k-1 disparity is below
    ``MIN_BIAS_DISPARITY_SIGMAS`` σ, where a second-order expansion does not hold.
    """
    base = h_prev(uvl0, uvr0)
    bias = np.zeros_like(base)
    for which, col in ((0, 0), (0, 1), (1, 0)):
        plus = [uvl0.copy(), uvr0.copy()]
        minus = [uvl0.copy(), uvr0.copy()]
        plus[which][:, col] += sigma_px
        minus[which][:, col] -= sigma_px
        bias += 0.5 * (h_prev(*plus) + h_prev(*minus) - 2.0 * base)
    valid = uvl0[:, 0] - uvr0[:, 0] >= MIN_BIAS_DISPARITY_SIGMAS * sigma_px  # (M,)
    bias = np.where(np.repeat(valid, 4), bias, 0.0)
    return np.where(np.isfinite(bias), bias, 0.0)


def whiten(Y: F64, W_inv: F64) -> F64:
    """Apply per-feature whitening ``W_inv`` (K, 4, 4) to rows of stacked 4-vectors (..., 4K)."""
    k = W_inv.shape[0]
    Yk = Y.reshape(*Y.shape[:-1], k, 4)
    return np.einsum("kij,...kj->...ki", W_inv, Yk).reshape(Y.shape)


def whiten_chol(Y: F64, L: F64) -> F64:
    """``whiten`` with the Cholesky factors ``L`` (K, d, d) (``R_m = L_m L_m^T``) instead of their
    inverses: each feature's d numbers of every row of ``Y`` (..., dK) times ``L_m^-1``, one
    batched solve for all rows (no explicit inverse)."""
    k, nb = L.shape[0], L.shape[1]
    b = Y.reshape(-1, k, nb)  # (rows, K, d)
    if not np.tril(L, -1).any():
        # Diagonal factors (the two-view blocks' σ I; the identity of ``vision_correlated``'s
        # second whitening): the substitution below reduces to this division, value for value
        # on finite rows (it subtracts exact zeros), in one pass over the rows instead of d².
        return (b / np.diagonal(L, axis1=1, axis2=2)).reshape(Y.shape)
    out = np.empty_like(b)
    # Forward substitution written out term by term, vectorised over rows and features (a
    # batched LU solve of 4x4 systems, or a reduction over an axis of 4, costs several times more).
    o = [out[..., i] for i in range(nb)]
    for i in range(nb):
        acc = b[..., i].copy()
        for j in range(i):
            acc -= L[:, i, j] * o[j]
        np.divide(acc, L[:, i, i], out=o[i])
    return out.reshape(Y.shape)


def lowrank_whiten(Y: F64, G: F64 | None) -> F64:
    """Rows of ``Y`` (..., n) times ``(I + G G^T)^-1/2`` (``G`` (n, k), thin): with ``G = U Σ V^T``,
    ``(I + G G^T)^-1/2 = I - U diag(1 - (1 + σ²)^-1/2) U^T``. ``G=None`` returns ``Y``."""
    U, d = lowrank_factors(G)
    if U is None:
        return Y
    return Y - ((Y @ U) * d) @ U.T


def lowrank_factors(G: F64 | None) -> tuple[F64 | None, F64 | None]:
    """``U`` (n, k) and ``d`` (k,) of ``lowrank_whiten`` (compute once, apply to many rows)."""
    if G is None:
        return None, None
    U, sv, _ = np.linalg.svd(G, full_matrices=False)
    return U, 1.0 - 1.0 / np.sqrt(1.0 + sv**2)


@dataclass(frozen=True)
class Whitening:
    """Rows (..., dK) of K features' stacked numbers to unit noise: each feature's d numbers
    times ``L_m^-1`` (``L`` (K, d, d), ``whiten_chol``), then times ``I - U diag(d) U^T``
    (``lowrank_whiten``'s form; ``U`` None: no low-rank term)."""

    L: F64
    U: F64 | None = None
    d: F64 | None = None

    @classmethod
    def of(cls, L: F64, G: F64 | None) -> Whitening:
        """Per-feature factors ``L`` and the low-rank term ``G`` (dK, k) already whitened by
        them (None: none): noise ``L L^T + G G^T`` in the original rows."""
        return cls(L, *lowrank_factors(G))

    def __call__(self, Y: F64) -> F64:
        Yw = whiten_chol(Y, self.L)
        return Yw if self.U is None else Yw - ((Yw @ self.U) * self.d) @ self.U.T


def _pixel_jacobian(p_C: F64, f: float, baseline: float) -> F64:
    """d(uL, vL, uR, vR)/d(p_C) (M, 4, 3) of left-camera points ``p_C`` (M, 3)."""
    x, y, z = p_C[:, 0], p_C[:, 1], p_C[:, 2]
    J = np.zeros((len(p_C), 4, 3))
    J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 0] = J[:, 3, 1] = f / z
    J[:, 0, 2] = -f * x / z**2
    J[:, 1, 2] = J[:, 3, 2] = -f * y / z**2
    J[:, 2, 2] = -f * (x - baseline) / z**2
    return J


def _triangulation_jacobian(uvl: F64, uvr: F64, f: float, cu: float, cv: float,
                            baseline: float) -> F64:
    """d(p_C)/d(u_left, v_left, u_right) (M, 3, 3) of eq. 10."""
    disp = uvl[:, 0] - uvr[:, 0]
    z = f * baseline / disp
    dz = z / disp  # dz/du_right = -dz/du_left
    J = np.zeros((len(uvl), 3, 3))
    J[:, 2, 0], J[:, 2, 2] = -dz, dz
    J[:, 0, 0] = z / f - (uvl[:, 0] - cu) / f * dz
    J[:, 0, 2] = (uvl[:, 0] - cu) / f * dz
    J[:, 1, 1] = z / f
    J[:, 1, 0] = -(uvl[:, 1] - cv) / f * dz
    J[:, 1, 2] = (uvl[:, 1] - cv) / f * dz
    return J


def analytic_noise(
    R_c: F64, r_c: F64, uvl0: F64, uvr0: F64, rig: RectifiedStereo, sigma_px: float,
    inc: ImuIncrement | None = None, dt_s: float = 0.0,
    densities: tuple[float, float] | None = None,
    p_Ckm1_F: F64 | None = None,
) -> tuple[F64, F64 | None]:
    """Closed-form twins of ``previous_pixel_noise`` and ``increment_noise_factor`` for the
    rigid-motion prediction ``d_k = R_c d - r_c`` (both ``3d`` and, in a rectified pair, ``tc``):
    ``R_blocks`` (M, 4, 4) and ``G`` (4M, 6) (None without ``inc``/``densities``).

    ``R_c`` (3, 3), ``r_c`` (3,) at the mean state (``vision_common.camera_motion``);
    ``p_Ckm1_F`` (M, 3) the k-1 pixels triangulated (eq. 10), if the caller has them already.
    """
    d = rig.triangulate(uvl0, uvr0) if p_Ckm1_F is None else p_Ckm1_F
    d_k = d @ R_c.T - r_c
    P = _pixel_jacobian(d_k, rig.f, rig.baseline)  # (M, 4, 3)
    T = _triangulation_jacobian(uvl0, uvr0, rig.f, rig.cu, rig.cv, rig.baseline)
    J = (P @ R_c) @ T
    J = np.where(np.isfinite(J), J, 0.0)
    R_blocks = sigma_px**2 * (np.eye(4) + J @ J.transpose(0, 2, 1))
    if inc is None or densities is None:
        return R_blocks, None
    C = np.asarray(rig.R_B_C, dtype=float)
    # d_k = C^T dRt (C d + c) - ...; ΔR -> ΔR Exp(δ) moves d_k by C^T [a]x δ, a = dRt (C d + c).
    dRt = np.asarray(inc.dR_Bkm1_Bk, dtype=float).T
    a = (d @ C.T + np.asarray(rig.p_B_C, float)) @ dRt.T
    std_rot = densities[0] * np.sqrt(dt_s)
    std_pos = densities[1] * np.sqrt(dt_s**3 / 3.0)
    D_rot = (C.T @ skew(a)) * std_rot  # C^T [a]x, (M, 3, 3)
    D_pos = np.broadcast_to(C.T * std_pos, D_rot.shape)
    G = P @ np.concatenate([D_rot, D_pos], axis=2)  # (M, 4, 6)
    return R_blocks, np.where(np.isfinite(G), G, 0.0).reshape(-1, 6)
