"""Compiled RANSAC kernels against independent numpy computations and finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from svains.frontend import egomotion_kernels as kern
from svains.frontend import egomotion_seeds as seeds
from svains.frontend.egomotion import reprojection_residuals
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp

RIG = RectifiedStereo(458.0, 367.0, 248.0, 0.11, np.eye(3), np.zeros(3), 752, 480)


def _problem(seed: int, n: int = 40):
    rng = np.random.default_rng(seed)
    p = np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(2, 15, n)]
    R_true, t_true = so3_exp(rng.normal(0, 0.05, 3)), rng.normal(0, 0.3, 3)
    q = p @ R_true.T + t_true
    uvl = RIG.project(q) + rng.normal(0, 0.5, (n, 2))
    uvr = RIG.project_right(q) + rng.normal(0, 0.5, (n, 2))
    R0 = so3_exp(rng.normal(0, 0.02, 3)) @ R_true  # a linearisation point near the truth
    t0 = t_true + rng.normal(0, 0.05, 3)
    w = (rng.random(n) > 0.2).astype(float)
    dvar = 2.0 * (p[:, 2] ** 2 / (RIG.f * RIG.baseline)) ** 2
    return p, uvl, uvr, R0, t0, w, dvar, R_true, t_true


def _resid(R, t, p, uvl, uvr):  # (M, 4)
    return reprojection_residuals(R[None], t[None], p, uvl, uvr, RIG)[0][0]


@pytest.mark.parametrize("use_dvar", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_normal_equations_match_finite_differences(seed: int, use_dvar: bool) -> None:
    p, uvl, uvr, R0, t0, w, dvar, _, _ = _problem(seed)
    A, g, cost = kern.normal_equations(R0, t0, p, uvl, uvr, w, dvar, use_dvar, RIG.f, RIG.cu,
                                       RIG.cv, RIG.baseline)  # fmt: skip
    r0 = _resid(R0, t0, p, uvl, uvr)
    # Numerical Jacobian d r / d (δθ, δt) with the left update R <- Exp(δθ) R.
    h = 1e-6
    J = np.zeros((p.shape[0], 4, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        rp = _resid(so3_exp(d[:3]) @ R0, t0 + d[3:], p, uvl, uvr)
        rm = _resid(so3_exp(-d[:3]) @ R0, t0 - d[3:], p, uvl, uvr)
        J[:, :, i] = (rp - rm) / (2 * h)
    # Per-feature weight: (I + s2 a aᵀ)^-1, a = d r / d depth at k-1 (numerical).
    W = np.broadcast_to(np.eye(4), (p.shape[0], 4, 4)).copy()
    if use_dvar:
        eps = 1e-5
        ray = p / p[:, 2:3]
        a = (_resid(R0, t0, p + eps * ray, uvl, uvr) - _resid(R0, t0, p - eps * ray, uvl, uvr))
        a /= 2 * eps
        W = np.linalg.inv(W + dvar[:, None, None] * a[:, :, None] * a[:, None, :])
    W *= w[:, None, None]
    A_ref = np.einsum("mki,mkl,mlj->ij", J, W, J)
    g_ref = np.einsum("mki,mkl,ml->i", J, W, r0)
    cost_ref = np.einsum("mk,mkl,ml->", r0, W, r0)
    np.testing.assert_allclose(A, A_ref, rtol=1e-5, atol=1e-6 * np.abs(A_ref).max())
    np.testing.assert_allclose(g, g_ref, rtol=1e-5, atol=1e-6 * np.abs(g_ref).max())
    assert cost == pytest.approx(cost_ref, rel=1e-9)


def test_gauss_newton_batch_converges_and_ignores_zero_weights() -> None:
    p, uvl, uvr, R0, t0, w, dvar, R_true, t_true = _problem(3, n=200)
    # Noise-free pixels for the weighted features, garbage for the others.
    q = p @ R_true.T + t_true
    uvl, uvr = RIG.project(q), RIG.project_right(q)
    uvl[w == 0] += 25.0
    R, t = R0[None].copy(), t0[None].copy()
    kern.gauss_newton_batch(R, t, p[None], uvl[None], uvr[None], w[None], dvar[None], True,
                            RIG.f, RIG.cu, RIG.cv, RIG.baseline, 10, 1e-12)  # fmt: skip
    assert np.abs(R[0] - R_true).max() < 1e-9 and np.abs(t[0] - t_true).max() < 1e-9


def test_score_matches_numpy_and_never_counts_points_behind_the_camera() -> None:
    p, uvl, uvr, R0, t0, _, _, R_true, t_true = _problem(4, n=120)
    p[:5, 2] = -1.0  # behind the camera
    rng = np.random.default_rng(5)
    Rh = np.stack([R_true, R0, so3_exp(rng.normal(0, 0.1, 3))])
    th = np.stack([t_true, t0, t_true + 0.5])
    score, inl = kern.score_batch(Rh, th, p, uvl, uvr, RIG.f, RIG.cu, RIG.cv, RIG.baseline, 1.5)
    for h in range(3):
        q = p @ Rh[h].T + th[h]
        with np.errstate(invalid="ignore", divide="ignore"):
            el = np.linalg.norm(RIG.project(q) - uvl, axis=1)
            er = np.linalg.norm(RIG.project_right(q) - uvr, axis=1)
        e = np.where(q[:, 2] > 1e-3, np.maximum(el, er), np.inf)
        ref = e < 1.5
        assert np.array_equal(inl[h], ref)
        assert score[h] == pytest.approx(ref.sum() - e[ref].sum() / (1.5 * 121), rel=1e-12)
    assert not inl[:, :5].any()
    assert inl[0].sum() > 0.9 * 115  # the true motion explains the data


def test_align_batch_equals_the_svd_solution_and_handles_nan() -> None:
    rng = np.random.default_rng(7)
    H = 300
    P = rng.normal(0, 3, (H, 3, 3))
    R_true = np.stack([so3_exp(rng.normal(0, 1.0, 3)) for _ in range(H)])
    C = np.einsum("hij,hmj->hmi", R_true, P) + rng.normal(0, 1, (H, 1, 3))
    C += rng.normal(0, 0.3, C.shape)  # noisy: the least-squares answer is not R_true
    C[0, 1, 2] = np.nan
    R, t = np.empty((H, 3, 3)), np.empty((H, 3))
    seeds.align_batch(P, C, R, t)
    assert np.array_equal(R[0], np.eye(3)) and np.array_equal(t[0], np.zeros(3))
    # Reference: SVD of the cross-covariance (Kabsch/Umeyama without scale).
    a = P[1:] - P[1:].mean(1, keepdims=True)
    b = C[1:] - C[1:].mean(1, keepdims=True)
    U, _, Vt = np.linalg.svd(np.einsum("hmi,hmj->hij", b, a))
    D = np.broadcast_to(np.eye(3), U.shape).copy()
    D[:, 2, 2] = np.sign(np.linalg.det(U @ Vt))
    R_ref = U @ D @ Vt
    np.testing.assert_allclose(R[1:], R_ref, atol=1e-9)
    t_ref = C[1:].mean(1) - np.einsum("hij,hj->hi", R_ref, P[1:].mean(1))
    np.testing.assert_allclose(t[1:], t_ref, atol=1e-9)
