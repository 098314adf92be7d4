"""Scaled symmetric sigma points (van der Merwe): 2n+1 points, weights from alpha, beta, kappa."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError, FilterError

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)

# Round-off tolerance of ``safe_cholesky``, per dimension, relative to the largest eigenvalue of
# the matrix scaled to unit diagonal: a positive semi-definite matrix formed in float64 (weighted
# sums of outer products, ``J P J^T``, ``P - K S K^T``) carries errors of order c·n·eps of its
# scale (Higham, "Accuracy and Stability of Numerical Algorithms", ch. 10), so its smallest
# computed eigenvalue may come out that negative. 100·n·eps (5e-13 for n = 24) leaves room for a
# few such operations in a row; a negative variance that means something (a bug, a bad noise
# matrix) is many orders of magnitude larger and still raises.
PSD_TOL_PER_DIM = 100.0 * float(np.finfo(np.float64).eps)

# Floor of the repaired eigenvalues, relative to the largest (of the matrix scaled to unit
# diagonal): above the tolerance for any size the filter uses (n < 4500), so the repaired
# matrix stays positive definite through the next sums of products, and far below any real
# variance (the standard deviation it adds along a null direction is 1e-5 of the entry's own).
EIG_FLOOR = 1e-10


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
    """Lower Cholesky factor (n, n) of a symmetric positive definite ``P`` (n, n).

    A matrix positive semi-definite up to round-off (e.g. a covariance with an exact pose
    clone) is repaired instead of refused: symmetrised, scaled to unit diagonal (the state
    mixes m², rad² and bias units, and round-off is relative to each entry's own scale), its
    eigenvalues clamped to ``EIG_FLOOR`` times the largest, factorised (logged at debug level).
    Non-finite entries, or a smallest eigenvalue below ``-PSD_TOL_PER_DIM·n`` times the largest,
    raise ``FilterError`` naming ``what``. A plain Cholesky success is returned untouched.
    """
    if not np.all(np.isfinite(P)):
        raise FilterError(f"{what} has non-finite entries")
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    S = 0.5 * (P + P.T)
    repaired = _repaired_cholesky(S)
    if repaired is None:
        eig = np.linalg.eigvalsh(S)
        raise FilterError(
            f"{what} is not positive definite (smallest eigenvalue {eig[0]:.3e}, "
            f"largest {eig[-1]:.3e}, size {P.shape[0]})"
        )
    L, e_min, e_max = repaired
    log.debug(
        "%s: positive semi-definite to round-off, eigenvalues clamped (smallest %.3e, largest "
        "%.3e at unit diagonal, size %d)", what, e_min, e_max, P.shape[0],
    )
    return L


def _repaired_cholesky(S: F64) -> tuple[F64, float, float] | None:
    """Lower factor (n, n) of symmetric ``S`` (n, n) with eigenvalues clamped at unit diagonal,
    and the smallest and largest eigenvalue there; None when ``S`` is not PSD to round-off."""
    n = S.shape[0]
    tol = PSD_TOL_PER_DIM * n
    d = np.diag(S)
    d_max = float(d.max())
    if not d_max > 0.0 or d.min() < -tol * d_max:
        return None
    s = np.sqrt(np.maximum(d, EIG_FLOOR * d_max))
    e, V = np.linalg.eigh(S / np.outer(s, s))
    e_min, e_max = float(e[0]), float(e[-1])
    if e_min < -tol * e_max:
        return None
    # B = V sqrt(e) has B B^T = the clamped matrix; B^T = Q R gives it as R^T R with R^T lower
    # triangular, without a second Cholesky that could fail again.
    R = np.linalg.qr((V * np.sqrt(np.maximum(e, EIG_FLOOR * e_max))).T, mode="r")
    L = s[:, None] * R.T
    L *= np.where(np.diag(R) < 0.0, -1.0, 1.0)  # a positive diagonal, like Cholesky's
    return L, e_min, e_max
