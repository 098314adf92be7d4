"""Scaled symmetric sigma points (van der Merwe): 2n+1 points, weights from alpha, beta, kappa."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError, FilterError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class MerweScaledSigmaPoints:
    """Sigma points ``0, ±sqrt(n+λ) L_i`` (L the Cholesky factor of P), ``λ = α²(n+κ) − n``.

    ``Wm`` (2n+1,) weights the mean, ``Wc`` (2n+1,) the covariance (``Wc0 = Wm0 + 1 − α² + β``).
    The class defaults α=1, β=2, κ=0 give W0m = 0 and all other weights positive; for κ=0 and
    β=2, ``Wc0 = 4 − α² − α⁻²`` stays non-negative down to α = sqrt(2 − sqrt(3)) ≈ 0.5176 (the
    run default, ``navigation.options.FilterOptions.alpha``), which keeps the predicted
    covariance a positive combination; ``Wm0`` is then negative (the manifold mean allows it).
    """

    n: int
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    Wm: F64 = field(init=False, repr=False)
    Wc: F64 = field(init=False, repr=False)
    scale: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.n < 1:
            raise ConfigError(f"sigma points need n >= 1, got {self.n}")
        lam = self.alpha**2 * (self.n + self.kappa) - self.n
        if self.n + lam <= 0.0:
            raise ConfigError(
                f"n + lambda = {self.n + lam:g} <= 0 (alpha={self.alpha}, kappa={self.kappa})"
            )
        wm = np.full(2 * self.n + 1, 0.5 / (self.n + lam))
        wm[0] = lam / (self.n + lam)
        wc = wm.copy()
        wc[0] += 1.0 - self.alpha**2 + self.beta
        object.__setattr__(self, "Wm", wm)
        object.__setattr__(self, "Wc", wc)
        object.__setattr__(self, "scale", float(np.sqrt(self.n + lam)))

    @property
    def num_points(self) -> int:
        return 2 * self.n + 1

    def offsets(self, P: F64) -> F64:
        """Tangent offsets (2n+1, n) of the sigma points for covariance ``P`` (n, n)."""
        L = safe_cholesky(P, "sigma-point covariance")
        out = np.zeros((2 * self.n + 1, self.n))
        out[1 : self.n + 1] = self.scale * L.T
        out[self.n + 1 :] = -self.scale * L.T
        return out


def safe_cholesky(P: F64, what: str) -> F64:
    """Lower Cholesky factor of a symmetric PD matrix; ``FilterError`` naming ``what`` if not PD."""
    if not np.all(np.isfinite(P)):
        raise FilterError(f"{what} has non-finite entries")
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(0.5 * (P + P.T))
        raise FilterError(
            f"{what} is not positive definite (smallest eigenvalue {eig[0]:.3e}, "
            f"largest {eig[-1]:.3e}, size {P.shape[0]})"
        ) from None
