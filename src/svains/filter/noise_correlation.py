"""Measurement noise that two updates share: its cross-covariance with the state, kept exact.

When one noise vector ``n`` (k,) enters two updates (a pixel measured at frame k is the far end
of the k-1 -> k frame pair and the near end of k -> k+1), the first update leaves the state
error ``x̃ = x - x̂`` correlated with ``n``: ``C = E[x̃ n^T] = -K B Σ`` (``K`` the gain, ``B``
the update's sensitivity to ``n``, ``Σ`` its covariance). Ignoring ``C`` at the second update
counts ``n`` twice (overconfident); leaving the pixel out of one update (single use) throws
information away. The first update also estimates the noise, ``n̂ = Σ B^T S⁻¹ ν`` (``ν`` its
innovation, ``S`` its covariance), which the second update's prediction must include. This
module keeps both and uses them:

- :class:`NoiseCorrelation` follows ``C`` through everything the filter does in between, as a
  UKF observer (``UKF.observers``): a prediction maps it by its statistical linearisation
  ``A`` (``C <- A C``; the process noise is independent of ``n``), an update by
  ``I - K H = P⁺ P⁻¹`` (the pseudo-inverse where ``P`` is singular, e.g. right after a pose is
  cloned: ``C`` lies in the range of ``P``), a change of state space by its tangent map. Only
  the small product of those maps is kept and applied when ``C`` is asked for. An update also
  moves ``n̂`` by ``C^T P⁻¹ δx̂`` (its gain on ``n`` is ``C^T H^T S⁻¹ = C^T P⁻¹ K``);
- :func:`decorrelated` turns the second update into an ordinary one: with ``n = G x̃ + e``,
  ``G = C^T P⁻¹`` (``n`` regressed on the state error) and ``e`` independent of ``x̃``
  (covariance ``Σ_n - C^T P⁻¹ C``, ``Σ_n`` the noise's own posterior covariance),
  ``z = h(x) + A n + w`` becomes ``z = h(x) + A n̂ + A G (x ⊟ x̂) + A e + w``: a model with a
  linear term in the sigma points' tangent offsets from the prior mean and the noise of
  ``A e + w``. Exact for linear models (``tests/test_filter_noise_correlation.py`` checks it
  against a Kalman filter that carries ``n`` in its state).

Pure numpy; the filter's conventions (``ukf``: tangent errors, ``x ⊟ x̂`` by
``Manifold.local``). Knows nothing of cameras.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from svains.errors import FilterError
from svains.filter.manifold import Manifold

F64 = NDArray[np.float64]
# Relative cut-off of P's eigenvalues at unit diagonal in the pseudo-inverse (an exact clone
# leaves one at round-off).
_RCOND = 1e-10


def pinv_psd(P: F64) -> F64:
    """A generalised inverse ``X`` (``P X P = P``) of a symmetric positive semi-definite ``P``
    (n, n), cut at ``_RCOND`` at unit diagonal: ``D⁻¹ (D⁻¹ P D⁻¹)⁺ D⁻¹``, ``D`` the standard
    deviations. Cut on ``P`` as it is, a state mixing m² and (rad/s)² lost real directions
    (units x1e3 / x1e-3 moved the mean by 8 % of a standard deviation: a review)."""
    S = 0.5 * (P + P.T)
    d = np.sqrt(np.clip(np.diag(S), 0.0, None))
    d[d == 0.0] = 1.0
    dd = np.outer(d, d)
    return np.linalg.pinv(S / dd, rcond=_RCOND, hermitian=True) / dd


class NoiseCorrelation:
    """The joint estimate of the state error and a stored noise vector ``n`` (k,): ``C =
    E[x̃ n^T]`` (ndx, k), the noise's estimate ``mean`` ``n̂`` (k,) and its covariance
    ``Σ_n = blocks ⊕ + C₀^T M C₀``, followed through predictions, updates and resizes (the
    ``RtsRecorder`` observer calls).

    At creation ``C`` = ``C₀`` and ``M`` = ``P⁺⁻¹`` of the update that measured ``n``:
    ``Σ_n = Σ - Σ B^T R⁻¹ B Σ + C^T P⁺⁻¹ C`` for noise ``R`` of that update (information form), so
    ``blocks`` (m, b, b), block-diagonal over groups of b entries (k = m b), is
    ``Σ - Σ B^T R⁻¹ B Σ``: what the update learnt of ``n`` from its own residuals. Predictions
    leave ``Σ_n`` alone, updates lower it by ``C^T P⁻¹ (P - P⁺) P⁻¹ C``. ``keys`` (m,) label
    the groups for the caller (e.g. track ids), ``t_ns`` when the noise was measured. ``valid``
    turns false when a change of state space has no known tangent map."""

    def __init__(
        self, C: F64, mean: F64, P_post: F64, blocks: F64, keys: NDArray[np.int64], t_ns: int,
    ) -> None:
        self._C = np.asarray(C, dtype=float)
        self.mean = np.asarray(mean, dtype=float).copy()
        self._M = pinv_psd(np.asarray(P_post, dtype=float))
        self.blocks = np.asarray(blocks, dtype=float)
        self.keys = np.asarray(keys)
        self.t_ns = int(t_ns)
        self._phi: F64 | None = None  # product of the maps since C was set (None: identity)
        self.valid = True

    def _map(self, M: F64) -> None:
        self._phi = M if self._phi is None else M @ self._phi

    def _maps(self) -> F64:
        """The product of the maps since ``C`` was set (ndx, ndx0)."""
        return np.eye(self._C.shape[0]) if self._phi is None else self._phi

    def current(self) -> F64:
        """``C`` (ndx, k) for the state as it is now."""
        return self._C if self._phi is None else self._phi @ self._C

    def unexplained(self, P: F64, P_inv: F64 | None = None) -> tuple[F64, F64]:
        """``(C₀ (ndx0, k), M' (ndx0, ndx0))`` with ``Σ_n - C^T P⁻¹ C = blocks ⊕ + C₀^T M' C₀``
        for the current covariance ``P``: the noise's covariance given the state error (its
        part the state does not explain). ``P_inv``: ``pinv_psd(P)`` if the caller has it."""
        phi = self._maps()
        Mp = self._M - phi.T @ (pinv_psd(P) if P_inv is None else P_inv) @ phi
        # A covariance: round-off of the difference (M holds P⁻¹, up to 1e9) clipped at zero.
        w, V = np.linalg.eigh(0.5 * (Mp + Mp.T))
        return self._C, (V * np.maximum(w, 0.0)) @ V.T

    def predicted(self, x_prior: F64, P_prior: F64, A: F64, x_post: F64) -> None:
        """A prediction with statistical linearisation ``A`` (ndx', ndx)."""
        self._map(A)

    def updated(self, manifold: Manifold, x_prior: F64, P_prior: F64, x_post: F64,
                P_post: F64) -> None:  # fmt: skip
        """An accepted update of an independent measurement: ``n̂ <- n̂ + C^T P⁻¹ δx̂``,
        ``Σ_n <- Σ_n - C^T P⁻¹ (P - P⁺) P⁻¹ C``, ``C <- P⁺ P⁻¹ C``."""
        if getattr(manifold, "consider", None) is not None:
            # a Schmidt update keeps the consider block: P⁺P⁻¹ is then not I - KH, and δx̂ lacks
            # the consider rows of K ν (a review: C off by 0.24 of 0.29)
            raise FilterError("NoiseCorrelation: an update with consider parameters cannot be "
                              "followed (the noise's correlation needs the full update)")
        Pi = pinv_psd(P_prior)
        dx = manifold.local(np.asarray(x_post, float)[None, :], np.asarray(x_prior, float))[0]
        PiPhi = Pi @ self._maps()
        # (Φ C₀)^T P⁻¹ δx̂ without forming Φ C₀ (ndx × k) at every update between frames.
        self.mean = self.mean + self._C.T @ (PiPhi.T @ dx)
        self._M = self._M - PiPhi.T @ (P_prior - P_post) @ PiPhi
        self._map(P_post @ Pi)

    def resized(self, x_prior: F64, P_prior: F64, transform: F64 | None, x_post: F64,
                P_post: F64) -> None:  # fmt: skip
        """The state space changed with tangent map ``transform`` (ndx', ndx); None: unknown."""
        if transform is None:
            self.valid = False
            return
        self._map(np.asarray(transform, dtype=float))


def decorrelated(
    h: Callable[[F64], F64], manifold: Manifold, x0: F64, P0: F64, AC: F64, A_mean: F64,
    P0_inv: F64 | None = None,
) -> Callable[[F64], F64]:
    """The update ``z = h(x) + A n + w`` with ``n`` estimated as ``n̂`` and correlated with the
    prior's error, ``C = E[x̃ n^T]``, as an update with independent noise ``A e + w``
    (``e = n - n̂ - C^T P0⁻¹ x̃``, covariance ``NoiseCorrelation.unexplained``): its model
    ``h'(X) = h(X) + A n̂ + A C^T P0⁻¹ (X ⊟ x0)`` for sigma points ``X`` (S, nx) of any mean
    (iterated updates). ``AC`` = ``A C^T`` (nz, ndx) and ``A_mean`` = ``A n̂`` (nz,) (the caller
    knows the structure of ``A``); ``x0`` (nx,), ``P0`` (ndx, ndx) the prior (``P0_inv``:
    ``pinv_psd(P0)`` if the caller has it)."""
    AG = AC @ (pinv_psd(P0) if P0_inv is None else P0_inv)  # (nz, ndx): A n regressed on x̃
    offset = np.asarray(A_mean, dtype=float)

    def h2(X: F64) -> F64:
        dX = manifold.local(X, x0)
        return np.asarray(h(X), dtype=float).reshape(X.shape[0], -1) + offset + dX @ AG.T

    return h2
