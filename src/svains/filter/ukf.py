"""Unscented Kalman filter on a manifold, additive noise in the tangent space.

Noise model (why additive, not augmented): the process noise of an INS is a white acceleration and
rate noise that enters the error state (nearly) linearly over one IMU step, so adding ``Q`` in
the tangent space after the sigma-point propagation loses almost nothing against the augmented
filter while keeping ``2n+1`` (25 or 37) sigma points instead of ``2(n+nq)+1``: the cost of a
prediction is half. The same holds for measurement noise ``R``.

The filter knows nothing about sensors: predictions take ``f(X (S, nx), u, dt) -> (S, nx)`` and
updates ``h(X (S, nx)) -> (S, nz)``, both vectorised over the S sigma points.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg
import scipy.special
from numpy.typing import NDArray

from svains.errors import ConfigError, FilterError
from svains.filter.iterated import iterated_update
from svains.filter.manifold import Manifold
from svains.filter.rts import RtsRecorder
from svains.filter.sigma_points import MerweScaledSigmaPoints, safe_cholesky

F64 = NDArray[np.float64]
ProcessFn = Callable[[F64, Any, float], F64]
MeasurementFn = Callable[[F64], F64]
ResidualFn = Callable[[F64, F64], F64]

_GATE_CACHE: dict[tuple[float, int], float] = {}


def chi2_gate(probability: float, dof: int) -> float:
    """Chi-square quantile for the gate (cached).

    ``2 gammaincinv(dof/2, p)`` is what ``scipy.stats.chi2.ppf`` evaluates, bit for bit
    (tests/test_filter_ukf.py); importing scipy.stats for it would cost every run ~0.5 s.
    """
    key = (probability, dof)
    if key not in _GATE_CACHE:
        _GATE_CACHE[key] = float(2.0 * scipy.special.gammaincinv(dof / 2.0, probability))
    return _GATE_CACHE[key]


@dataclass(frozen=True)
class UpdateStats:
    """Outcome of one update: ``nis`` = r^T S^-1 r, ``dof`` = nz, ``gate`` threshold (inf: none);
    ``whitened`` (nz,) = L^-1 r with S = L L^T where the update forms S (``update_blocks``:
    the low-dimensional sensors), else None. Its mean over a run of updates is a bias test;
    a caller may set another white quantity of the update there (``navigation`` puts a vision
    update's whitened state correction, ``fault_handling.whitened_correction``). ``residual``
    (nz,) the innovation ``r`` and ``innovation_cov`` (nz, nz) its covariance ``S`` where
    ``update_blocks`` forms them; ``offset_refused``: the block
    passed the gate but its innovation was closer to the offset given for it (see
    ``update_blocks``)."""

    name: str
    accepted: bool
    nis: float
    dof: int
    gate: float
    whitened: F64 | None = field(default=None, compare=False, repr=False)
    residual: F64 | None = field(default=None, compare=False, repr=False)
    offset_refused: bool = False
    innovation_cov: F64 | None = field(default=None, compare=False, repr=False)
    # ``update_blocks(contribution_of=name)``: this accepted block's share of the joint update,
    # (dx (ndx,), dP (ndx, ndx)) = the update with every kept block minus the update without it
    # (prior tangent; the same sigma points), what un-fusing it would take back.
    contribution: tuple[F64, F64] | None = field(default=None, compare=False, repr=False)


class UKF:
    """Sigma-point filter with mean ``x`` (nx,) on ``manifold`` and tangent covariance ``P``."""

    def __init__(
        self, manifold: Manifold, points: MerweScaledSigmaPoints, x0: F64, P0: F64
    ) -> None:
        if points.n != manifold.ndx:
            raise ConfigError(f"sigma points for n={points.n}, manifold has ndx={manifold.ndx}")
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        if x0.shape != (manifold.nx,) or P0.shape != (manifold.ndx, manifold.ndx):
            raise ConfigError(
                f"x0 {x0.shape} / P0 {P0.shape} do not match nx={manifold.nx}, ndx={manifold.ndx}"
            )
        self.manifold = manifold
        self.points = points
        self.x = x0.copy()
        self.P = 0.5 * (P0 + P0.T)
        safe_cholesky(self.P, "initial covariance")
        self._sigma_cache: tuple[bytes, F64, F64] | None = None
        # Sees every change of the state for a smoother (``filter.rts``); None: not recorded.
        self.recorder: RtsRecorder | None = None
        # Further observers of the same calls (e.g. ``noise_correlation.NoiseCorrelation``).
        self.observers: list[Any] = []
        # The gain K^T (nz, ndx) of the last accepted ``update`` (None: none yet, or
        # ``update_blocks``); callers that track noise correlations read it.
        self.last_gain_T: F64 | None = None
        # ... and its S^-1 r (nz,) (r the innovation, S its covariance): the same callers
        # estimate the noise they follow from it.
        self.last_innovation_solve: F64 | None = None

    def sigma_points(self) -> tuple[F64, F64]:
        """Sigma points ``X`` (S, nx) of the current state and their tangent offsets (S, ndx).

        Read-only arrays, reused while ``x`` and ``P`` keep their values (an updater that gates
        features on the sigma points, then updates, draws them once: one Cholesky, not two).
        """
        key = self.x.tobytes() + self.P.tobytes()
        cached = self._sigma_cache
        if cached is not None and cached[0] == key:
            return cached[1], cached[2]
        dX = self.points.offsets(self.P)
        X = self.manifold.retract(np.broadcast_to(self.x, (dX.shape[0], self.x.size)), dX)
        X.flags.writeable = False
        dX.flags.writeable = False
        self._sigma_cache = (key, X, dX)
        return X, dX

    def resize(self, manifold: Manifold, x: F64, P: F64, transform: F64 | None = None) -> None:
        """Replace the state space (augmenting or marginalising states, e.g. pose clones) with
        its mean ``x`` (nx,) and covariance ``P`` (ndx, ndx); the sigma-point parameters stay.
        ``transform`` (ndx, ndx_old): the linear tangent map the change applied (a copy, a
        selection), for a smoother (``recorder``); without it the recorder cuts its chain."""
        x_old, P_old = self.x, self.P
        p = self.points
        self.points = MerweScaledSigmaPoints(manifold.ndx, p.alpha, p.beta, p.kappa)
        self.manifold = manifold
        self._sigma_cache = None
        self.x = np.asarray(x, dtype=float).copy()
        self.P = 0.5 * (P + P.T)
        if self.x.shape != (manifold.nx,) or self.P.shape != (manifold.ndx, manifold.ndx):
            raise ConfigError(
                f"x {self.x.shape} / P {self.P.shape} do not match nx={manifold.nx}, "
                f"ndx={manifold.ndx}"
            )
        for obs in self._watching():
            obs.resized(x_old, P_old, transform, self.x, self.P)

    def predict(self, f: ProcessFn, u: Any, dt: float, Q: F64) -> None:
        """Propagate through ``f(X, u, dt)`` and add ``Q`` (n, n) or its diagonal (n,).

        ``Q`` may cover only the leading n <= ndx tangent components: the trailing ones (e.g.
        pose clones, which ``f`` must leave unchanged) get no process noise.
        """
        X, _ = self.sigma_points()
        Y = f(X, u, dt)
        if not np.all(np.isfinite(Y)):
            raise FilterError("process model returned non-finite sigma points")
        x = self.manifold.mean(Y, self.points.Wm)
        dY = self.manifold.local(Y, x)
        P = dY.T @ (self.points.Wc[:, None] * dY)
        n = np.shape(Q)[0]
        if n > P.shape[0]:
            raise ConfigError(f"process noise of size {n} for a {P.shape[0]}-dim tangent")
        P[:n, :n] += np.diag(Q) if np.ndim(Q) == 1 else Q
        if watching := self._watching():
            # The step's statistical linearisation A = P_xy^T P^-1 (the sigma points' own).
            _, dX = self.sigma_points()
            A = _regression(self.P, dX.T @ (self.points.Wc[:, None] * dY))
            for obs in watching:
                obs.predicted(self.x, self.P, A, x)
        self.x = x
        self.P = 0.5 * (P + P.T)

    def update_blocks(
        self,
        blocks: list[tuple[MeasurementFn, F64, F64, ResidualFn | None, str]],
        gate_probability: float | None = None,
        offsets: Mapping[str, F64] | None = None,
        contribution_of: str | None = None,
    ) -> list[UpdateStats]:
        """Fuse several independent measurements ``(h, z, R, residual, name)`` taken at the same
        time with ONE sigma-point draw: each block is gated on its own marginal innovation
        covariance, the accepted ones are fused together in one update (R block-diagonal).
        ``offsets`` maps a block's name to an offset ``d`` (nz,) its sensor is suspected of:
        the block is also refused when its innovation is nearer ``d`` than zero in the metric
        of its innovation covariance (``(r - d)' S⁻¹ (r - d) < r' S⁻¹ r``), i.e. when the
        measurement fits "offset by ``d``" better than "right". ``contribution_of``: the name
        of a block whose share of the update its stats carry (``UpdateStats.contribution``).
        """
        if not blocks:
            return []
        X, dX = self.sigma_points()
        Wm, Wc = self.points.Wm, self.points.Wc
        stats: list[UpdateStats] = []
        kept: list[tuple[F64, F64, F64]] = []  # (dY, r, R as a matrix)
        kept_at: list[int] = []  # their positions in ``stats``
        for h, z, R, residual, name in blocks:
            z = np.asarray(z, dtype=float).ravel()
            nz = z.size
            R = np.asarray(R, dtype=float)
            Rm = np.diag(R) if R.ndim == 1 else R
            if Rm.shape != (nz, nz):
                raise ConfigError(f"{name or 'measurement'}: R has shape {R.shape}, z has {nz}")
            Y = np.asarray(h(X), dtype=float).reshape(X.shape[0], nz)
            y = Wm @ Y
            dY = Y - y if residual is None else residual(Y, y)
            r = z - y if residual is None else residual(z, y)
            S = dY.T @ (Wc[:, None] * dY) + Rm
            L = safe_cholesky(0.5 * (S + S.T), f"innovation covariance of {name or 'measurement'}")
            w = scipy.linalg.solve_triangular(L, r, lower=True, check_finite=False)
            nis = float(w @ w)
            gate = chi2_gate(gate_probability, nz) if gate_probability is not None else np.inf
            if not np.isfinite(nis):
                raise FilterError(f"{name or 'measurement'}: non-finite innovation")
            ok = nis <= gate
            refused = False
            d = None if offsets is None else offsets.get(name)
            if ok and d is not None and np.size(d) == nz:  # another layout: no test
                w_d = scipy.linalg.solve_triangular(L, r - np.asarray(d, dtype=float).ravel(),
                                                    lower=True, check_finite=False)  # fmt: skip
                refused = bool(w_d @ w_d < nis)
                ok = not refused
            stats.append(UpdateStats(name, ok, nis, nz, float(gate), w, r.copy(), refused, S))
            if ok:
                kept.append((dY, r, Rm))
                kept_at.append(len(stats) - 1)
        if kept:
            label = "+".join(s.name for s in stats if s.accepted)
            dx, dP = _stacked_gain(dX, Wc, kept, label)
            for j, i in enumerate(kept_at):
                if stats[i].name == contribution_of:
                    others = kept[:j] + kept[j + 1 :]
                    dx_o, dP_o = (_stacked_gain(dX, Wc, others, label) if others
                                  else (np.zeros_like(dx), np.zeros_like(dP)))  # fmt: skip
                    stats[i] = replace(stats[i], contribution=(dx - dx_o, dP - dP_o))
            self._set_posterior(self.manifold.retract(self.x[None, :], dx[None, :])[0],
                                self.P - dP)  # fmt: skip
            self.last_gain_T = self.last_innovation_solve = None  # the stacked gain is not kept
        return stats

    def update(
        self,
        h: MeasurementFn,
        z: F64,
        R: F64,
        gate_probability: float | None = None,
        residual: ResidualFn | None = None,
        name: str = "",
        R_low_rank: F64 | None = None,
        iterations: int = 1,
        max_nis_per_dof: float | None = None,
    ) -> UpdateStats:
        """Fuse ``z`` (nz,) with model ``h`` and noise ``R`` (nz, nz) or diagonal (nz,).

        ``R_low_rank`` ``D`` (k, nz), k small, adds ``D^T D`` to the noise (noise common to many
        measurement components, e.g. a shared input's error seen through ``h``); with a diagonal
        ``R`` the update then stays O(S² nz) (see ``kalman_correction``).
        With ``gate_probability`` the update is skipped (``accepted=False``) when the NIS exceeds
        the chi-square quantile of that probability with nz degrees of freedom, or
        ``max_nis_per_dof`` times nz when that is given and smaller (a test for many stacked
        measurements that flags a bad linearisation without refusing every slightly
        imperfect model: at 480 dof the 0.999 quantile is 1.21 nz).
        ``iterations`` > 1 re-linearises ``h`` over the posterior that many times
        (``filter.iterated``, plain residuals only; O(nz (S + ndx)²) with a diagonal ``R`` and
        many measurements, else O(nz³)); the gate then uses the last linearisation's NIS.
        """
        z = np.asarray(z, dtype=float).ravel()
        R = np.asarray(R, dtype=float)
        nz = z.size
        if R.shape not in ((nz,), (nz, nz)):
            raise ConfigError(f"{name or 'measurement'}: R has shape {R.shape}, z has {nz} entries")
        D = None if R_low_rank is None else np.asarray(R_low_rank, dtype=float)
        if D is not None and (D.ndim != 2 or D.shape[1] != nz):
            raise ConfigError(
                f"{name or 'measurement'}: R_low_rank has shape {D.shape}, expected (k, {nz})"
            )
        if iterations > 1:
            if residual is not None:
                raise ConfigError(f"{name or 'measurement'}: iterated updates need plain residuals")
            return self._update_iterated(h, z, R, D, _gate(gate_probability, max_nis_per_dof, nz),
                                         name, iterations)  # fmt: skip
        X, dX = self.sigma_points()
        Y = np.asarray(h(X), dtype=float).reshape(X.shape[0], nz)
        Wc = self.points.Wc
        y = self.points.Wm @ Y
        dY = Y - y if residual is None else residual(Y, y)
        r = z - y if residual is None else residual(z, y)
        # The matrix-inversion-lemma path pays off for many measurements (or a low-rank term).
        fast = R.ndim == 1 and (nz > 2 * X.shape[0] or D is not None)
        dx, nis, dP, gain = _correction(dX, dY, Wc, R, r, D, name, fast)
        gate = _gate(gate_probability, max_nis_per_dof, nz)
        if not np.isfinite(nis):
            raise FilterError(f"{name or 'measurement'}: non-finite innovation")
        if nis > gate:
            return UpdateStats(name, False, float(nis), nz, float(gate))
        self._set_posterior(self.manifold.retract(self.x[None, :], dx[None, :])[0], self.P - dP)
        self.last_gain_T, self.last_innovation_solve = gain
        return UpdateStats(name, True, float(nis), nz, float(gate))

    def update_linear(
        self, H: F64, r: F64, R: F64, C: F64 | None = None,
        gate_probability: float | None = None, name: str = "",
    ) -> UpdateStats:
        """A linear(ised) update with innovation ``r = H e + v`` (nz,): ``H`` (nz, ndx) maps the
        tangent error ``e`` (true ⊟ estimate), the noise ``v`` has covariance ``R`` (nz, nz) and
        may share an error with the state, ``C = Cov(e, v)`` (ndx, nz) (None: independent),
        as the exact Kalman update of the state augmented by that shared error gives it:
        ``S = H P Hᵀ + R + H C + Cᵀ Hᵀ``, gain ``(P Hᵀ + C) S⁻¹``; gated as ``update``,
        the mean retracted and recorded as an update's."""
        H = np.asarray(H, dtype=float)
        r = np.asarray(r, dtype=float).ravel()
        nz = r.size
        C = np.zeros((H.shape[1], nz)) if C is None else np.asarray(C, dtype=float)
        P_xy = self.P @ H.T + C
        S = H @ P_xy + C.T @ H.T + np.asarray(R, dtype=float)
        S = 0.5 * (S + S.T)
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError as exc:
            raise FilterError(f"{name or 'measurement'}: innovation covariance not positive "
                              "definite") from exc  # fmt: skip
        w = np.linalg.solve(L, r)
        nis = float(w @ w)
        gate = _gate(gate_probability, None, nz)
        if not np.isfinite(nis):
            raise FilterError(f"{name or 'measurement'}: non-finite innovation")
        if nis > gate:
            return UpdateStats(name, False, nis, nz, float(gate))
        K = np.linalg.solve(S, P_xy.T).T
        self._set_posterior(self.manifold.retract(self.x[None, :], (K @ r)[None, :])[0],
                            self.P - K @ S @ K.T)  # fmt: skip
        # (no gain of ``update``'s form: a caller reading the last one must not take an older)
        self.last_gain_T = self.last_innovation_solve = None
        return UpdateStats(name, True, nis, nz, float(gate), whitened=w)

    def set_posterior(self, x: F64, P: F64) -> None:
        """Replace the estimate at this instant as an update does (symmetrised), the recorder
        and observers told so: for a change that is no prediction, such as updates taken
        back (``navigation.unfuse``), which a smoother then bridges instead of cutting."""
        self._set_posterior(x, P)

    def _set_posterior(self, x: F64, P: F64) -> None:
        """Take an accepted update's mean and covariance (symmetrised), telling the recorder.
        The manifold's consider parameters (``Manifold`` docstring) keep their prior mean and
        covariance block: with the gain's rows for them zeroed, the Schmidt update's other
        blocks, cross-covariances included, are the full update's."""
        x_prior, P_prior = self.x, self.P
        consider = getattr(self.manifold, "consider", None)
        if consider is not None:
            cx, cdx = consider
            x, P = np.array(x, dtype=float), np.array(P, dtype=float)
            x[cx] = x_prior[cx]
            P[cdx, cdx] = P_prior[cdx, cdx]
        self.x = x
        self.P = 0.5 * (P + P.T)
        for obs in self._watching():
            obs.updated(self.manifold, x_prior, P_prior, self.x, self.P)

    def _watching(self) -> list[Any]:
        """The recorder and the observers, in that order."""
        return self.observers if self.recorder is None else [self.recorder, *self.observers]

    def _update_iterated(
        self, h: MeasurementFn, z: F64, R: F64, D: F64 | None, gate: float, name: str,
        iterations: int,
    ) -> UpdateStats:
        """``update`` with ``iterations`` posterior linearisations (``filter.iterated``) and the
        NIS threshold ``gate`` (inf: none)."""
        x, P, nis, gain = iterated_update(self.manifold, self.points, self.x, self.P, h, z, R,
                                        iterations, name or "measurement", D)  # fmt: skip
        if not np.isfinite(nis):
            raise FilterError(f"{name or 'measurement'}: non-finite innovation")
        if nis > gate:
            return UpdateStats(name, False, nis, z.size, float(gate))
        self._set_posterior(x, P)
        self.last_gain_T, self.last_innovation_solve = gain
        return UpdateStats(name, True, nis, z.size, float(gate))


def _regression(P: F64, Pxy: F64) -> F64:
    """``A = Pxy^T P^-1`` (ndx', ndx): the linear map that best explains the propagated sigma
    points from the prior ones (exact for a linear model)."""
    try:
        return np.linalg.solve(P, Pxy).T
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(P, Pxy, rcond=None)[0].T


def _gate(probability: float | None, max_nis_per_dof: float | None, nz: int) -> float:
    """NIS threshold of an update (``UKF.update``); inf without a test."""
    gate = chi2_gate(probability, nz) if probability is not None else np.inf
    return gate if max_nis_per_dof is None else min(gate, max_nis_per_dof * nz)


def kalman_correction(
    dX: F64,
    dY: F64,
    Wc: F64,
    R: F64,
    r: F64,
    R_low_rank: F64 | None = None,
    name: str = "",
    allow_woodbury: bool = True,
) -> tuple[F64, float, F64]:
    """Sigma-point Kalman correction: state step ``dx`` (ndx,), NIS and covariance decrease.

    ``dX`` (S, ndx) tangent offsets of the sigma points, ``dY`` (S, nz) their measurement
    deviations from the predicted mean, ``Wc`` (S,) covariance weights, ``r`` (nz,) innovation,
    noise ``R`` (nz, nz) or its diagonal (nz,) plus ``D^T D`` for ``R_low_rank`` = D (k, nz).
    ``dx = K r``, ``NIS = r^T S^-1 r``, ``dP = K S K^T`` with ``S = dY^T Wc dY + R (+ D^T D)``.

    A diagonal ``R`` with non-negative weights takes the matrix-inversion-lemma path in
    O(S² nz) when ``allow_woodbury``: the rows of D join the sigma points' deviations with zero
    state offset and unit weight (their ``A^T A`` adds ``D^T D``). Otherwise S (nz, nz) is
    formed and Cholesky-solved.
    """
    return _correction(dX, dY, Wc, R, r, R_low_rank, name, allow_woodbury)[:3]


def _correction(
    dX: F64, dY: F64, Wc: F64, R: F64, r: F64, R_low_rank: F64 | None, name: str,
    allow_woodbury: bool,
) -> tuple[F64, float, F64, tuple[F64, F64] | None]:
    """``kalman_correction`` and (the gain ``K^T`` (nz, ndx), ``S^-1 r`` (nz,))."""
    R = np.asarray(R, dtype=float)
    D = R_low_rank
    if allow_woodbury and R.ndim == 1 and np.all(Wc >= 0.0):
        if D is not None:
            dY = np.vstack([dY, D])
            dX = np.vstack([dX, np.zeros((D.shape[0], dX.shape[1]))])
            Wc = np.concatenate([Wc, np.ones(D.shape[0])])
        return _woodbury_gain(dX, dY, Wc, R, r)
    Rm = np.diag(R) if R.ndim == 1 else R
    if D is not None:
        Rm = Rm + D.T @ D
    return _dense_gain(dX, dY, Wc, Rm, r, name)


def _stacked_gain(
    dX: F64, Wc: F64, kept: list[tuple[F64, F64, F64]], name: str
) -> tuple[F64, F64]:
    """Correction and covariance decrease of blocks ``(dY, r, R)`` fused together (R
    block-diagonal)."""
    dY = np.concatenate([k[0] for k in kept], axis=1)
    r = np.concatenate([k[1] for k in kept])
    R = np.zeros((r.size, r.size))
    i = 0
    for _, _, Rk in kept:
        R[i : i + len(Rk), i : i + len(Rk)] = Rk
        i += len(Rk)
    dx, _, dP, _ = _dense_gain(dX, dY, Wc, R, r, name)
    return dx, dP


def _dense_gain(
    dX: F64, dY: F64, Wc: F64, R: F64, r: F64, name: str
) -> tuple[F64, float, F64, tuple[F64, F64]]:
    """Correction, NIS, covariance decrease and (gain ``K^T`` (nz, ndx), ``S^-1 r`` (nz,)) with a
    Cholesky solve of S (nz, nz)."""
    WdY = Wc[:, None] * dY
    S = dY.T @ WdY
    S += np.diag(R) if R.ndim == 1 else R
    Pxz = dX.T @ WdY
    L = safe_cholesky(0.5 * (S + S.T), f"innovation covariance of {name or 'measurement'}")
    # K^T = S^-1 Pxz^T (solve, never invert).
    KT = scipy.linalg.cho_solve((L, True), Pxz.T, check_finite=False)
    w = scipy.linalg.solve_triangular(L, r, lower=True, check_finite=False)
    Sr = scipy.linalg.solve_triangular(L, w, lower=True, trans="T", check_finite=False)
    return KT.T @ r, float(w @ w), Pxz @ KT, (KT, Sr)


def _woodbury_gain(
    dX: F64, dY: F64, Wc: F64, Rdiag: F64, r: F64
) -> tuple[F64, float, F64, tuple[F64, F64]]:
    """Same as ``_dense_gain`` for a diagonal R and nz >> S, in O(S² nz) (matrix inversion lemma).

    With ``A = sqrt(Wc) dY`` (S, nz), ``C = sqrt(Wc) dX`` (S, ndx), ``B = A R^-1`` and
    ``M = I + B A^T``: ``K = C^T M^-1 B``, ``K S K^T = C^T (I - M^-1) C`` and
    ``S^-1 = R^-1 - B^T M^-1 B``.
    """
    sw = np.sqrt(Wc)[:, None]
    A = sw * dY
    C = sw * dX
    B = A / Rdiag
    M = np.eye(A.shape[0]) + B @ A.T
    L = safe_cholesky(0.5 * (M + M.T), "Woodbury capacitance matrix")
    Br = B @ r
    # One solve for both right-hand sides (S, 1 + ndx).
    Mi = scipy.linalg.cho_solve((L, True), np.column_stack([Br, C]), check_finite=False)
    MiBr, MiC = Mi[:, 0], Mi[:, 1:]
    nis = float(r @ (r / Rdiag) - Br @ MiBr)
    return C.T @ MiBr, nis, C.T @ (C - MiC), (B.T @ MiC, r / Rdiag - B.T @ MiBr)
