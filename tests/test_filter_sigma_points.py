"""Sigma points reproduce the mean and covariance they were drawn from."""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError, FilterError
from svains.filter import Euclidean, MerweScaledSigmaPoints


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
