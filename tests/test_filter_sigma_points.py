"""Sigma points reproduce the mean and covariance they were drawn from."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from svains.errors import ConfigError, FilterError
from svains.filter import Euclidean, MerweScaledSigmaPoints, safe_cholesky


def _random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n) * 0.1


@pytest.mark.parametrize(
    ("n", "alpha", "beta", "kappa"), [(3, 1.0, 2.0, 0.0), (12, 0.5, 2.0, 0.0), (18, 1e-3, 2.0, 1.0)]
)
def test_sigma_points_reproduce_mean_and_covariance(
    n: int, alpha: float, beta: float, kappa: float
) -> None:
    rng = np.random.default_rng(n)
    P = _random_spd(rng, n)
    x = rng.normal(size=n)
    sp = MerweScaledSigmaPoints(n, alpha, beta, kappa)
    m = Euclidean(n)
    X = m.retract(np.tile(x, (sp.num_points, 1)), sp.offsets(P))
    mean = m.mean(X, sp.Wm)
    d = X - mean
    np.testing.assert_allclose(sp.Wm.sum(), 1.0, atol=1e-12)
    np.testing.assert_allclose(mean, x, atol=1e-12 * max(1.0, np.abs(X).max()))
    cov = (d * sp.Wc[:, None]).T @ d  # the centre point has d = 0, so Wc and Wm agree here
    np.testing.assert_allclose(cov, P, rtol=0, atol=1e-12 * np.abs(P).max())


def test_covariance_weights_with_beta_add_to_the_centre_only() -> None:
    sp = MerweScaledSigmaPoints(4, alpha=0.5, beta=2.0)
    np.testing.assert_allclose(sp.Wc[1:], sp.Wm[1:])
    assert sp.Wc[0] == pytest.approx(sp.Wm[0] + 1 - 0.25 + 2.0)
    assert sp.num_points == 9


def test_bad_parameters_and_covariance_raise_clear_errors() -> None:
    with pytest.raises(ConfigError, match="n >= 1"):
        MerweScaledSigmaPoints(0)
    with pytest.raises(ConfigError, match="n \\+ lambda"):
        MerweScaledSigmaPoints(3, alpha=1.0, kappa=-3.0)
    sp = MerweScaledSigmaPoints(2)
    with pytest.raises(FilterError, match=r"not positive definite.*smallest eigenvalue -1"):
        sp.offsets(np.diag([1.0, -1.0]))
    with pytest.raises(FilterError, match="non-finite"):
        sp.offsets(np.array([[1.0, np.nan], [np.nan, 1.0]]))


@pytest.mark.parametrize("n", [12, 18, 24, 36, 60])
def test_default_alpha_keeps_every_covariance_weight_non_negative(n: int) -> None:
    from svains.navigation.options import FilterOptions

    o = FilterOptions()
    sp = MerweScaledSigmaPoints(n, o.alpha, o.beta, o.kappa)
    assert sp.Wc.min() >= 0.0  # the Woodbury gain path needs it (filter.ukf.kalman_correction)
    assert sp.scale < np.sqrt(n)  # tighter than alpha = 1
    # Just below the bound sqrt(2 - sqrt(3)) the centre weight turns negative.
    assert MerweScaledSigmaPoints(n, 0.517, o.beta, o.kappa).Wc[0] < 0.0


# --- Covariances positive semi-definite to round-off (exact pose clones): repaired, not refused.


def _clone_augmented(seed: int, jitter: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A biased navigation covariance with ~100 m position deviations (λmax 1e4) augmented by a
    pose clone (``models.clones.augment_clone``, ``jitter`` None: its default): P' (24, 24), P
    (18, 18)."""
    from svains.models.clones import CloneManifold, augment_clone
    from svains.models.manifold import NavManifold
    from svains.models.state import BIASED

    rng = np.random.default_rng(seed)
    x = rng.normal(size=BIASED.nx)
    x[6:10] /= np.linalg.norm(x[6:10])
    A = rng.normal(size=(BIASED.ndx, BIASED.ndx)) * 0.1
    P = A @ A.T + 1e-3 * np.eye(BIASED.ndx)
    s = np.ones(BIASED.ndx)
    s[0:3] = 100.0
    P = s[:, None] * P * s[None, :]
    P *= 1e4 / np.linalg.eigvalsh(P)[-1]
    _, P1, _ = augment_clone(x, P, CloneManifold(NavManifold(BIASED)), jitter)
    return P1, P


@pytest.mark.parametrize("jitter", [None, 0.0], ids=["default-jitter", "exact-copy"])
@pytest.mark.parametrize("seed", range(8))
def test_sigma_points_of_a_clone_augmented_covariance_reproduce_it(
    seed: int, jitter: float | None
) -> None:
    # An exact copy (jitter 0) is singular: Cholesky fails and the repair must factor it; the
    # default, scale-relative jitter is enough on its own at λmax 1e4 (an absolute 1e-12 is not).
    P1, _ = _clone_augmented(seed, jitter)
    if jitter == 0.0:
        with pytest.raises(np.linalg.LinAlgError):
            np.linalg.cholesky(P1)
    sp = MerweScaledSigmaPoints(P1.shape[0], alpha=0.5176)
    d = sp.offsets(P1)
    assert d.shape == (sp.num_points, P1.shape[0])
    cov = (d * sp.Wc[:, None]).T @ d
    np.testing.assert_allclose(cov, P1, rtol=0, atol=1e-8 * np.abs(P1).max())


def test_repaired_factor_is_lower_triangular_with_a_positive_diagonal_and_logged(
    caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    P1, _ = _clone_augmented(0, jitter=0.0)
    with caplog.at_level(logging.DEBUG, logger="svains.filter.sigma_points"):
        L = safe_cholesky(P1, "test covariance")
    np.testing.assert_array_equal(L, np.tril(L))
    assert np.all(np.diag(L) > 0.0)
    np.testing.assert_allclose(L @ L.T, P1, rtol=0, atol=1e-8 * np.abs(P1).max())
    assert any("test covariance" in r.getMessage() and r.levelno == logging.DEBUG
               for r in caplog.records)  # fmt: skip
    assert capsys.readouterr() == ("", "")  # logged, never printed


def test_a_clearly_indefinite_matrix_still_raises_naming_its_smallest_eigenvalue() -> None:
    rng = np.random.default_rng(3)
    n = 24
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    e = np.logspace(-4, 4, n)
    e[0] = -1e-3 * e[-1]  # -10 against λmax 1e4: a real loss of definiteness, not round-off
    P = (Q * e) @ Q.T
    P = 0.5 * (P + P.T)
    with pytest.raises(FilterError, match=r"test covariance is not positive definite "
                       r"\(smallest eigenvalue -1\.000e\+01, largest 1\.000e\+04, size 24\)"):
        safe_cholesky(P, "test covariance")
    with pytest.raises(FilterError, match="not positive definite"):
        MerweScaledSigmaPoints(n).offsets(P)
    with pytest.raises(FilterError, match="not positive definite"):
        safe_cholesky(np.zeros((3, 3)), "zero")
    P[0, 0] = np.inf
    with pytest.raises(FilterError, match="non-finite"):
        safe_cholesky(P, "test covariance")


@pytest.mark.parametrize("n", [1, 6, 24])
def test_a_positive_definite_matrix_gives_exactly_numpy_cholesky(n: int) -> None:
    rng = np.random.default_rng(n)
    s = np.sqrt(np.logspace(-6, 4, n))
    P = s[:, None] * _random_spd(rng, n) * s[None, :]  # badly scaled, still PD
    P = 0.5 * (P + P.T)
    L = safe_cholesky(P, "test")
    np.testing.assert_array_equal(L, np.linalg.cholesky(P))
    sp = MerweScaledSigmaPoints(n, alpha=0.5176)
    d = sp.offsets(P)
    np.testing.assert_array_equal(d[1 : n + 1], sp.scale * np.linalg.cholesky(P).T)
