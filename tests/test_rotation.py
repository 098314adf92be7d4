"""Group identities and conventions of the quaternion helpers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from svains.geometry import rotation as rot


def _random_quats(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rot.quat_normalize(rng.normal(size=(n, 4)))


def test_rotmat_matches_scipy_hamilton_scalar_first() -> None:
    q = _random_quats(50)
    R_ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(rot.quat_to_rotmat(q), R_ref, atol=1e-12)
    np.testing.assert_allclose(rot.rotmat_to_quat(R_ref), q, atol=1e-12)


def test_product_composes_matrices() -> None:
    p, q = _random_quats(20, 1), _random_quats(20, 2)
    lhs = rot.quat_to_rotmat(rot.quat_multiply(p, q))
    rhs = rot.quat_to_rotmat(p) @ rot.quat_to_rotmat(q)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)


def test_exp_log_roundtrip_including_tiny_and_near_pi() -> None:
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(30, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-12, 1e-9, 1e-6], rng.uniform(0, 3.1, 25), [np.pi - 1e-6]])
    theta = axes * angles[:, None]
    np.testing.assert_allclose(rot.quat_log(rot.quat_exp(theta)), theta, atol=1e-9)
    R = rot.so3_exp(theta)
    R_ref = Rotation.from_rotvec(theta).as_matrix()
    np.testing.assert_allclose(R, R_ref, atol=1e-12)


def test_box_plus_minus_inverse_and_local_convention() -> None:
    q = _random_quats(10, 4)
    d = np.random.default_rng(5).normal(scale=0.3, size=(10, 3))
    q2 = rot.quat_box_plus(q, d)
    np.testing.assert_allclose(rot.quat_box_minus(q2, q), d, atol=1e-12)
    # Local (body) perturbation: R2 = R Exp(d).
    np.testing.assert_allclose(
        rot.quat_to_rotmat(q2), rot.quat_to_rotmat(q) @ rot.so3_exp(d), atol=1e-12
    )


def test_rotate_and_skew() -> None:
    q = _random_quats(10, 6)
    v = np.random.default_rng(7).normal(size=(10, 3))
    np.testing.assert_allclose(
        rot.quat_rotate(q, v), np.einsum("nij,nj->ni", rot.quat_to_rotmat(q), v), atol=1e-12
    )
    w = np.array([0.3, -1.0, 2.0])
    np.testing.assert_allclose(rot.skew(w) @ v[0], np.cross(w, v[0]), atol=1e-14)


def test_quat_average_recovers_symmetric_spread() -> None:
    mean = _random_quats(1, 8)[0]
    d = np.array([[0.1, 0, 0], [-0.1, 0, 0], [0, 0.2, 0], [0, -0.2, 0]])
    qs = rot.quat_box_plus(mean[None], d)
    avg = rot.quat_average(qs, np.ones(4))
    np.testing.assert_allclose(rot.quat_box_minus(avg, mean), 0.0, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-8, 0.3, 1.2, 2.8])
def test_the_inverse_right_jacobian_maps_a_body_perturbation_into_the_chart(angle: float) -> None:
    """``Log(Exp(θ) Exp(δ)) - θ ≈ J_r⁻¹(θ) δ`` by finite differences (the bank of headings
    takes a copy's covariance into another's chart with it)."""
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    theta = angle * axis / np.linalg.norm(axis)
    J = rot.so3_right_jacobian_inv(theta)
    h = 1e-6
    num = np.column_stack([
        (rot.so3_log(rot.so3_exp(theta) @ rot.so3_exp(h * e))
         - rot.so3_log(rot.so3_exp(theta) @ rot.so3_exp(-h * e)))
        / (2 * h) for e in np.eye(3)
    ])  # fmt: skip
    np.testing.assert_allclose(J, num, atol=1e-6)
