"""The vision updater's gates, in their chi-square band (issue 26: a per-feature gate with the
wrong degrees of freedom survived the suite).

Monte Carlo: features whose 4 pixels are a linear function of a Gaussian state, measured with
noise exactly as modelled. Their NIS is then chi-square with 4 degrees of freedom, and the gate
at probability p keeps a fraction p of them.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from svains.filter.sigma_points import MerweScaledSigmaPoints
from svains.navigation.options import FilterOptions
from svains.navigation.vision_noise import feature_gate

N_STATE = 6
M = 20_000  # features


def _consistent_features(seed: int) -> tuple[np.ndarray, MerweScaledSigmaPoints, np.ndarray,
                                               np.ndarray]:  # fmt: skip
    """Sigma-point predictions ``Y`` (S, 4M), the points, ``z`` (4M,) and ``R_blocks`` (M, 4,
    4) of features ``z_m = H_m x + e_m``, x ~ N(x̂, P), e_m ~ N(0, R_m)."""
    rng = np.random.default_rng(seed)
    pts = MerweScaledSigmaPoints(N_STATE, alpha=FilterOptions().alpha)
    A = rng.normal(size=(N_STATE, N_STATE))
    P = 0.1 * (A @ A.T) + 0.05 * np.eye(N_STATE)
    x_hat = rng.normal(size=N_STATE)
    X = x_hat + pts.offsets(P)  # (S, n)
    H = rng.normal(size=(M, 4, N_STATE))
    B = rng.normal(size=(M, 4, 4))
    R = 0.3 * B @ B.transpose(0, 2, 1) + 0.2 * np.eye(4)
    Y = np.einsum("mdn,sn->smd", H, X).reshape(len(X), 4 * M)
    # State error (a fresh draw per feature: independent features) and measurement noise as
    # modelled, so each innovation is N(0, H_m P H_mᵀ + R_m).
    dx = rng.normal(size=(M, N_STATE)) @ np.linalg.cholesky(P).T
    e = np.einsum("mij,mj->mi", np.linalg.cholesky(R), rng.normal(size=(M, 4)))
    z = np.einsum("mdn,mn->md", H, x_hat + dx) + e
    return Y, pts, z.reshape(-1), R


@pytest.mark.parametrize("probability", [0.9, FilterOptions().gate_probability])
def test_feature_gate_keeps_its_probability_of_consistent_features(probability: float) -> None:
    Y, pts, z, R = _consistent_features(seed=3)
    keep, finite, nis = feature_gate(Y, pts.Wm, pts.Wc, z, R, probability)
    assert finite.all()
    # NIS of consistent 4-pixel features: chi-square(4), mean 4 (measured 3.991; limit 3
    # standard errors of the mean of 20000 draws, 3 sqrt(8 / 20000) = 0.06).
    assert abs(nis.mean() - 4.0) < 0.06, nis.mean()
    kept = keep.mean()
    # Kept fraction p within 4 standard errors sqrt(p (1 - p) / M) (measured: 0.8985 at 0.9,
    # 0.7 standard errors off; 0.99925 at 0.999).
    assert abs(kept - probability) < 4.0 * np.sqrt(probability * (1 - probability) / M), kept
    # The gate is the chi-square(4) quantile itself.
    q = stats.chi2.ppf(probability, 4)
    np.testing.assert_array_equal(keep, nis <= q)
