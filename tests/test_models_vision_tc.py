"""Trifocal tensor and point transfer (H&Z 17.12, algorithm 16.2) on generic views."""

from __future__ import annotations

import itertools

import numpy as np

from svains.geometry.rotation import so3_exp
from svains.models.vision_tc import (
    fundamental_from_projections,
    perpendicular_lines,
    transfer_points,
    trifocal_tensor,
)


def _random_views(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    K = np.array([[500.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])
    P_a = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    Rb, Rc = so3_exp(rng.normal(0, 0.1, 3)), so3_exp(rng.normal(0, 0.1, 3))
    P_b = K @ np.hstack([Rb, rng.normal(0, 0.5, (3, 1))])
    P_c = K @ np.hstack([Rc, rng.normal(0, 0.5, (3, 1))])
    X = np.column_stack([rng.uniform(-2, 2, 20), rng.uniform(-2, 2, 20), rng.uniform(4, 9, 20)])
    return P_a, P_b, P_c, X


def _proj(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    p = np.hstack([X, np.ones((len(X), 1))]) @ P.T
    return p[:, :2] / p[:, 2:]


def test_tensor_equals_determinant_definition() -> None:
    P_a, P_b, P_c, _ = _random_views(0)
    T = trifocal_tensor(P_a, P_b, P_c)
    for i, q, r in itertools.product(range(3), repeat=3):
        M = np.vstack([np.delete(P_a, i, axis=0), P_b[q], P_c[r]])
        assert np.isclose(T[i, q, r], (-1) ** i * np.linalg.det(M), rtol=1e-10, atol=1e-6)


def test_tensor_matches_canonical_form_for_identity_first_camera() -> None:
    # H&Z eq. 15.1: for P_a = [I | 0], P_b = [A | a4], P_c = [B | b4]: T_i = a_i b4^T - a4 b_i^T.
    rng = np.random.default_rng(3)
    P_a = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_b, P_c = rng.normal(size=(3, 4)), rng.normal(size=(3, 4))
    T = trifocal_tensor(P_a, P_b, P_c)
    canon = np.stack(
        [np.outer(P_b[:, i], P_c[:, 3]) - np.outer(P_b[:, 3], P_c[:, i]) for i in range(3)]
    )
    scale = T.ravel() @ canon.ravel() / (canon.ravel() @ canon.ravel())
    np.testing.assert_allclose(T, scale * canon, atol=1e-10)
    assert abs(abs(scale) - 1.0) < 1e-12


def test_point_transfer_reproduces_projection_in_third_view() -> None:
    P_a, P_b, P_c, X = _random_views(1)
    uv_a, uv_b, uv_c = _proj(P_a, X), _proj(P_b, X), _proj(P_c, X)
    F = fundamental_from_projections(P_a, P_b)
    # Epipolar constraint holds on exact correspondences.
    pa = np.hstack([uv_a, np.ones((20, 1))])
    pb = np.hstack([uv_b, np.ones((20, 1))])
    assert np.abs(np.einsum("mi,ij,mj->m", pb, F, pa)).max() < 1e-8 * np.abs(F).max() * 1e6
    lines = perpendicular_lines(F, uv_a, uv_b)
    np.testing.assert_allclose(np.einsum("mi,mi->m", lines, pb), 0.0, atol=1e-6)
    T = trifocal_tensor(P_a, P_b, P_c)
    np.testing.assert_allclose(transfer_points(T, uv_a, lines), uv_c, atol=1e-8)
    # Batched tensors (two copies) give the same result per batch element.
    out = transfer_points(np.stack([T, T]), uv_a, lines)
    assert out.shape == (2, 20, 2)
    np.testing.assert_allclose(out[1], uv_c, atol=1e-8)


def test_perpendicular_line_is_perpendicular_to_epipolar_line() -> None:
    P_a, P_b, _, X = _random_views(2)
    F = fundamental_from_projections(P_a, P_b)
    uv_a, uv_b = _proj(P_a, X), _proj(P_b, X)
    lines = perpendicular_lines(F, uv_a, uv_b)
    l_e = np.hstack([uv_a, np.ones((20, 1))]) @ F.T
    np.testing.assert_allclose(np.einsum("mi,mi->m", lines[:, :2], l_e[:, :2]), 0.0, atol=1e-9)
