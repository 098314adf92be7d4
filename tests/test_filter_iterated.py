"""Iterated posterior linearisation (``filter.iterated``) through ``UKF.update(iterations=)``."""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError
from svains.filter import UKF, Euclidean, MerweScaledSigmaPoints
from svains.models.manifold import NavManifold
from svains.models.state import BIASED


def _ukf(x0: np.ndarray, P0: np.ndarray) -> UKF:
    return UKF(Euclidean(x0.size), MerweScaledSigmaPoints(x0.size, alpha=0.52), x0, P0)


def test_a_linear_model_gives_the_plain_update_whatever_the_iterations() -> None:
    rng = np.random.default_rng(1)
    n, m = 5, 3
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    x0 = rng.normal(size=n)
    H = rng.normal(size=(m, n))
    z = rng.normal(size=m)
    R = np.full(m, 0.3)
    plain, iterated = _ukf(x0, P0), _ukf(x0, P0)
    s1 = plain.update(lambda X: X @ H.T, z, R)
    s3 = iterated.update(lambda X: X @ H.T, z, R, iterations=3)
    np.testing.assert_allclose(iterated.x, plain.x, atol=1e-10)
    np.testing.assert_allclose(iterated.P, plain.P, atol=1e-10)
    assert s3.nis == pytest.approx(s1.nis, rel=1e-9)


def test_iterating_reaches_what_a_precise_nonlinear_measurement_says() -> None:
    # Prior x ~ N(1, 0.5²); z = exp(x) measured to 0.2 %, true x = 2. One linearisation over
    # the wide prior stops 0.4 short and keeps a 0.17 std; re-linearising over the posterior
    # lands on log(z) with the measurement's own 0.002.
    x_true = 2.0
    z = np.array([np.exp(x_true)])
    R = np.array([(0.002 * z[0]) ** 2])
    plain = _ukf(np.array([1.0]), np.eye(1) * 0.25)
    iterated = _ukf(np.array([1.0]), np.eye(1) * 0.25)
    plain.update(np.exp, z, R)
    stats = iterated.update(np.exp, z, R, iterations=4)
    assert abs(plain.x[0] - x_true) > 0.3 and np.sqrt(plain.P[0, 0]) > 0.1
    assert iterated.x[0] == pytest.approx(x_true, abs=0.001)
    assert np.sqrt(iterated.P[0, 0]) == pytest.approx(0.002, rel=0.1)  # the Cramér-Rao bound
    assert stats.accepted


def test_iterating_on_the_navigation_manifold_keeps_a_unit_quaternion() -> None:
    rng = np.random.default_rng(4)
    m = NavManifold(BIASED)
    x0 = np.zeros(m.nx)
    x0[6] = 1.0
    P0 = np.eye(m.ndx) * 0.04
    truth = m.retract(x0[None], rng.normal(scale=0.2, size=(1, m.ndx)))[0]
    h = lambda X: X[:, 6:10] @ np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.5]])  # noqa: E731
    ukf = UKF(m, MerweScaledSigmaPoints(m.ndx, alpha=0.52), x0, P0)
    ukf.update(h, h(truth[None])[0], np.full(3, 1e-6), iterations=3)
    assert np.linalg.norm(ukf.x[6:10]) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(h(ukf.x[None])[0], h(truth[None])[0], atol=1e-3)


def test_iterated_updates_refuse_a_custom_residual() -> None:
    ukf = _ukf(np.zeros(2), np.eye(2))
    with pytest.raises(ConfigError, match="iterated updates need plain residuals"):
        ukf.update(lambda X: X, np.zeros(2), np.ones(2), residual=lambda a, b: a - b, iterations=2)


def test_an_exact_copy_in_the_prior_is_iterated_like_the_plain_update() -> None:
    # The third state copies the first (a pose clone without jitter): P0 is singular, the
    # sigma points and the regression ``H = Ψ^T P_j^-1`` both need the repaired factor.
    J = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    P0 = J @ np.array([[1e4, 0.3], [0.3, 2.0]]) @ J.T
    x0 = np.array([1.0, -2.0, 1.0])
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(P0)
    H = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0]])
    z, R = np.array([2.0, -1.0]), np.full(2, 0.1)
    plain, iterated = _ukf(x0, P0), _ukf(x0, P0)
    s1 = plain.update(lambda X: X @ H.T, z, R)
    s3 = iterated.update(lambda X: X @ H.T, z, R, iterations=3)
    np.testing.assert_allclose(iterated.x, plain.x, rtol=1e-6)
    # Both keep the repair's floor (1e-10 of the prior's scale) along the copy direction.
    np.testing.assert_allclose(iterated.P, plain.P, rtol=0, atol=1e-9 * np.abs(P0).max())
    assert s3.nis == pytest.approx(s1.nis, rel=1e-6)
    assert iterated.x[2] == pytest.approx(iterated.x[0], rel=1e-6)  # the copy moves along


def test_many_measurements_with_a_diagonal_noise_take_the_lemma_and_match_the_dense_path() -> None:
    """nz > 2 S with a diagonal R: the information form of ``iterated_update`` gives the dense
    path's posterior, NIS, gain and ``S⁻¹ r``."""
    from svains.filter.iterated import iterated_update

    rng = np.random.default_rng(0)
    n, nz = 4, 200
    H = rng.normal(size=(nz, n))

    def h(X: np.ndarray) -> np.ndarray:  # non-linear: the iterations matter
        return np.sin(0.3 * X @ H.T) + X[:, :1] ** 2

    x0, P0 = rng.normal(size=n), np.diag(rng.uniform(0.1, 1.0, n))
    R = rng.uniform(0.5, 1.0, nz)
    z = h(x0[None] + 0.3)[0]
    pts = MerweScaledSigmaPoints(n, alpha=0.7)
    lemma = iterated_update(Euclidean(n), pts, x0, P0, h, z, R, 4)
    dense = iterated_update(Euclidean(n), pts, x0, P0, h, z, np.diag(R), 4)
    for a, b in zip(lemma[:2], dense[:2], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert lemma[2] == pytest.approx(dense[2], rel=1e-10)
    for a, b in zip(lemma[3], dense[3], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_a_strong_frame_over_a_wide_prior_keeps_a_positive_definite_posterior() -> None:
    """Many precise measurements over a prior metres wide (EuRoC every 25th frame with
    correlated pixels: the earlier lemma's subtraction lost the small eigenvalues there): the
    information form gives the exact linear posterior ``(P0^-1 + H^T R^-1 H)^-1``, positive
    definite, where ``P0 - P0 H^T K^T`` is not."""
    from svains.filter.iterated import iterated_update

    rng = np.random.default_rng(2)
    n, nz = 6, 300
    H = rng.normal(size=(nz, n))
    x0 = rng.normal(size=n)
    P0 = np.diag([1e4, 1e4, 1e4, 1e2, 1.0, 1e4])  # λmax 1e4, as after a 5 s gap
    R = np.full(nz, 1e-6)
    z = H @ (x0 + 3.0)
    pts = MerweScaledSigmaPoints(n, alpha=0.52)
    x, P, _, (KT, _) = iterated_update(Euclidean(n), pts, x0, P0, lambda X: X @ H.T, z, R, 2)
    exact_P = np.linalg.inv(np.linalg.inv(P0) + H.T @ (H / R[:, None]))
    exact_x = x0 + exact_P @ (H.T @ ((z - H @ x0) / R))
    np.testing.assert_allclose(np.linalg.eigvalsh(P), np.linalg.eigvalsh(exact_P), rtol=1e-6)
    np.testing.assert_allclose(P, exact_P, rtol=0, atol=1e-10 * np.abs(exact_P).max())
    np.testing.assert_allclose(x, exact_x, rtol=1e-8)
    # What the subtraction form gives from the same gain: not a covariance any more.
    dense = P0 - P0 @ H.T @ KT
    assert np.linalg.eigvalsh(0.5 * (dense + dense.T))[0] < 0


def test_a_low_rank_noise_term_keeps_the_fast_path_and_matches_the_dense_one() -> None:
    """``R_low_rank`` D joins the linearisation error's factor: the same posterior, NIS and
    gain as a dense ``diag(R) + D^T D``; weights with a negative centre (alpha < 0.5176)
    take the dense path and agree too."""
    from svains.filter.iterated import iterated_update

    rng = np.random.default_rng(3)
    n, nz = 4, 120
    H = rng.normal(size=(nz, n))

    def h(X: np.ndarray) -> np.ndarray:
        return np.sin(0.3 * X @ H.T) + X[:, 1:2] ** 2

    x0, P0 = rng.normal(size=n), np.diag(rng.uniform(0.1, 1.0, n))
    R, D = rng.uniform(0.5, 1.0, nz), 0.3 * rng.normal(size=(2, nz))
    z = h(x0[None] + 0.3)[0]
    for alpha in (0.52, 0.3):
        pts = MerweScaledSigmaPoints(n, alpha=alpha)
        low = iterated_update(Euclidean(n), pts, x0, P0, h, z, R, 3, R_low_rank=D)
        dense = iterated_update(Euclidean(n), pts, x0, P0, h, z, np.diag(R) + D.T @ D, 3)
        for a, b in zip(low[:2], dense[:2], strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12)
        assert low[2] == pytest.approx(dense[2], rel=1e-10)
        for a, b in zip(low[3], dense[3], strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12)


def test_an_ill_conditioned_prior_is_repaired_without_a_warning() -> None:
    """A clone's exact copy direction leaves P with rcond ~1e-17: scipy solved it under a
    ``LinAlgWarning`` printed on the user's console (a probe's MH_03 at 0.2 Hz). It takes the
    repaired factorisation, as a failed one does, and gives a finite answer."""
    import warnings

    from svains.filter.iterated import _solve_psd

    rng = np.random.default_rng(1)
    A = rng.standard_normal((6, 6))
    T = np.vstack([np.eye(6), np.eye(6)[:3]])  # three states copied exactly
    P = T @ (A @ A.T * 1e6) @ T.T + 1e-10 * np.eye(9)  # factorises, rcond below eps
    B = np.ones((9, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        X = _solve_psd(P, B, "test")
    assert np.all(np.isfinite(X)) and X.shape == (9, 2)
