"""Generic sigma-point (unscented) Kalman filter on a manifold; knows nothing about sensors."""

from svains.filter.manifold import Euclidean, Manifold
from svains.filter.sigma_points import MerweScaledSigmaPoints, safe_cholesky
from svains.filter.ukf import UKF, UpdateStats, chi2_gate, kalman_correction

__all__ = [
    "UKF",
    "Euclidean",
    "Manifold",
    "MerweScaledSigmaPoints",
    "UpdateStats",
    "chi2_gate",
    "kalman_correction",
    "safe_cholesky",
]
