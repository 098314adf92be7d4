"""Unscented Rauch-Tung-Striebel smoothing of a finished ``UKF`` run, recorded as it runs.

The recorder (:class:`RtsRecorder`) rides along with a ``UKF`` (``UKF.recorder``) and sees
every operation that changes the state:

- ``predict``: the filter's own statistical linearisation ``A = P_xy^T P^-1`` (ndx', ndx) of the
  step, taken from the sigma points it propagated (``P_xy`` their cross-covariance; for a linear
  model ``A`` is the model's matrix). Chained over the predictions between two epochs, it gives
  the cross-covariance ``C = P_k Φ^T`` between the posterior at epoch k and the prediction at
  k+1 without re-linearising anything;
- ``resize`` with its linear map (a pose clone added is a copy, one dropped a selection);
- an accepted update: the prior ``(x⁻, P⁻)``, the posterior and its step ``Δ = x⁺ ⊟ x⁻``;
- anything else that moves the mean (a reset) cuts the chain: the epochs before it are
  smoothed with the data up to it only. A covariance changed in place (inflated, a gap's noise
  added) is process noise the next prediction's ``P⁻`` already holds.

Each update and each ``mark`` (an output time) is an epoch. The RTS gain between consecutive
epochs is ``G = C (P⁻)⁻¹``; in the tangent spaces of the posteriors, the smoothed correction
``ε_k = x_k^s ⊟ x_k`` and covariance follow ``ε_k = G (Δ_{k+1} + ε_{k+1})`` and
``P_k^s = M_k + G P_{k+1}^s G^T`` with ``M_k = P_k − G P⁻_{k+1} G^T`` (first order in the
difference between the prior's and the posterior's tangent spaces, as the filter itself).

Nothing is kept per update: the recursion is affine, so the epochs between two stored ones
are composed online. A stored *chain* epoch (every ``chain_interval_ns``, and the last) keeps
``ε_c = a_c + B_c ε_{c+1}`` and ``P_c^s = M_c + B_c P_{c+1}^s B_c^T`` for the whole state; the
other marks (*branches*) keep the same for their ``output_rows`` only, relative to the next
chain epoch. Memory: one chain epoch (ndx² numbers twice) per interval and
``r·ndx + r²`` per mark, r = the rows kept (``RtsRecorder.nbytes``).

:func:`smooth` runs the backward pass over a finished recording.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from svains.errors import ConfigError, FilterError

if TYPE_CHECKING:
    from svains.filter.manifold import Manifold

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@functools.cache
def _triu(n: int) -> tuple[I64, I64]:
    return np.triu_indices(n)  # type: ignore[return-value]


def _pack(M: F64) -> F64:
    """Upper triangle (row-major) of a symmetric matrix (n, n) -> (n(n+1)/2,)."""
    return M[_triu(M.shape[0])]


def _unpack(v: F64, n: int) -> F64:
    """Inverse of ``_pack``."""
    M = np.zeros((n, n))
    iu = _triu(n)
    M[iu] = v
    M.T[iu] = v
    return M


# the kept means of marks that keep none (``keep_x=0``), shared
_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False


@dataclass
class _Open:
    """An epoch whose smoothed value is not yet tied to a chain epoch: ``ε[rows] = a + B ε_now``
    and ``P^s[rows, rows] = M + B P^s_now B^T`` (``now``: the recorder's current posterior)."""

    index: int  # into RtsRecorder.marks (branch) or RtsRecorder.chain (chain epoch)
    chain: bool
    B: F64  # (r, ndx_now)
    a: F64  # (r,)
    M: F64  # (r, r)


@dataclass(slots=True)
class ChainEpoch:
    """A stored epoch of the whole state: ``ε = a + B ε_next`` (B (ndx, ndx_next)) and
    ``P^s = M + B P^s_next B^T``; the last one has ``B`` (ndx, 0) and ``M`` its own ``P``.
    ``M_packed``: M's upper triangle (``_pack``)."""

    t_ns: int
    B: F64
    a: F64
    M_packed: F64

    @property
    def M(self) -> F64:
        return _unpack(self.M_packed, self.a.size)


@dataclass(slots=True)
class MarkEpoch:
    """An output epoch: the forward mean's first ``keep_x`` entries ``x`` and, on the tangent
    ``rows``, ``ε[rows] = a + B ε_chain``, ``P^s[rows, rows] = M + B P^s_chain B^T`` relative
    to the chain epoch ``chain`` (an index into ``RtsRecorder.chain``, -1 until it is known).

    ``B`` is kept in float32 (half the memory of a mark): it only maps the chain epoch's
    correction and covariance, so its 6e-8 relative rounding gives errors of that order of
    the covariance's scale (a linear-Gaussian test: 3e-8 on entries of 5e-2), far below any
    variance; the chain epochs, whose gains multiply, stay float64. ``M_packed``: M's upper
    triangle. Once tied to a chain epoch, ``M_packed`` is float32 too (its terms are added to
    float64 ones, not multiplied along a chain: a covariance's 6e-8 relative rounding)."""

    t_ns: int
    x: F64
    rows: I64
    B: NDArray[np.float32] = field(repr=False)
    a: F64 = field(repr=False)
    M_packed: NDArray[np.floating] = field(repr=False)
    chain: int = -1


class RtsRecorder:
    """What a backward RTS pass needs, composed online from the forward filter's operations.

    ``output_rows``: the tangent rows a mark keeps (None: all); ``keep_x``: how many leading
    entries of the mean a mark keeps (None: all; a state that changes size between marks needs
    both given); ``chain_interval_ns``: the spacing of the stored whole-state epochs (a mark at
    least this long after the previous one becomes one).
    """

    def __init__(
        self,
        output_rows: I64 | None = None,
        keep_x: int | None = None,
        chain_interval_ns: int = 1_000_000_000,
    ) -> None:
        if chain_interval_ns <= 0:
            raise ConfigError(f"chain_interval_ns must be positive, got {chain_interval_ns}")
        self.output_rows = None if output_rows is None else np.asarray(output_rows, np.int64)
        self.keep_x = keep_x
        self.chain_interval_ns = int(chain_interval_ns)
        self.chain: list[ChainEpoch | None] = []
        self._chain_t: list[int] = []
        self.marks: list[MarkEpoch] = []
        self.cuts = 0
        self.updates = 0
        # An update saw consider parameters (``filter.manifold``): the backward pass below is no
        # smoother for a Schmidt forward run (it can end worse than the filter), so it refuses.
        self.considered = False
        self._open: list[_Open] = []
        self._x_post: F64 | None = None  # posterior of the last epoch
        self._P_post: F64 | None = None
        self._phi: F64 | None = None  # map from that posterior's tangent to now (None: I)
        self._x_seen: F64 | None = None  # the mean after the last operation seen
        self._last_chain_ns: int | None = None
        self.finished = False

    # ---- hooks called by the UKF ------------------------------------------------------------
    def _check(self, x: F64, P: F64) -> None:
        """A mean changed behind the recorder's back (a reset) cuts the chain."""
        if self._x_seen is not None and self._x_seen.tobytes() != np.asarray(x).tobytes():
            self.cut(x, P)

    def predicted(self, x_prior: F64, P_prior: F64, A: F64, x_post: F64) -> None:
        """A prediction with statistical linearisation ``A`` (ndx', ndx) took ``x_prior``
        (covariance ``P_prior``) to ``x_post``."""
        if self._x_post is None:
            return
        self._check(x_prior, P_prior)
        self._phi = A if self._phi is None else A @ self._phi
        self._x_seen = np.array(x_post, dtype=float)

    def resized(self, x_prior: F64, P_prior: F64, transform: F64 | None, x_post: F64,
                P_post: F64) -> None:
        """The state space changed from ``(x_prior, P_prior)`` to ``(x_post, P_post)`` with
        tangent map ``transform`` (ndx', ndx); None: unknown, which cuts the chain."""
        if self._x_post is None:
            return
        self._check(x_prior, P_prior)
        if transform is None:
            self.cut(x_post, P_post)
            return
        T = np.asarray(transform, dtype=float)
        self._phi = T if self._phi is None else T @ self._phi
        self._x_seen = np.array(x_post, dtype=float)

    def updated(self, manifold: Manifold, x_prior: F64, P_prior: F64, x_post: F64,
                P_post: F64) -> None:
        """An accepted update took ``(x_prior, P_prior)`` to ``(x_post, P_post)``."""
        if getattr(manifold, "consider", None) is not None:
            self.considered = True
        if self._x_post is None:
            return
        self._check(x_prior, P_prior)
        delta = manifold.local(np.asarray(x_post, dtype=float)[None, :], x_prior)[0]
        self._link(P_prior, delta)
        self._x_post, self._P_post = np.array(x_post, dtype=float), np.array(P_post, dtype=float)
        self._x_seen = self._x_post
        self.updates += 1

    # ---- calls from the application -----------------------------------------------------
    def start(self, x: F64, P: F64) -> None:
        """Begin at the filter's current ``x``, ``P`` (before any ``mark``)."""
        self._x_post, self._P_post = np.array(x, dtype=float), np.array(P, dtype=float)
        self._x_seen = self._x_post
        self._phi = None

    def cut(self, x: F64, P: F64) -> None:
        """The state was replaced by ``(x, P)``: nothing after this point smooths what came
        before (a gain of zero)."""
        if self._x_post is None or self._P_post is None:
            return
        n = np.shape(P)[0]
        for o in self._open:
            o.M += o.B @ self._P_post @ o.B.T
            o.B = np.zeros((o.B.shape[0], n))
        self._x_post = np.array(x, dtype=float)
        self._P_post = np.array(P, dtype=float)
        self._x_seen = self._x_post
        self._phi = None
        self.cuts += 1

    def mark(self, t_ns: int, x: F64, P: F64, last: bool = False) -> None:
        """An output epoch at ``t_ns`` with the filter's ``x``, ``P``; ``last``: the end of the
        run (a chain epoch that closes the recording)."""
        if self._x_post is None:
            raise FilterError("RtsRecorder.mark before start")
        if self.finished:
            raise FilterError("RtsRecorder.mark after the last epoch")
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        self._check(x, P)
        self._link(P, None)
        self._x_post, self._P_post = np.array(x), np.array(P)
        self._x_seen = self._x_post
        rows = np.arange(P.shape[0]) if self.output_rows is None else self.output_rows
        if rows.size and rows.max() >= P.shape[0]:
            raise ConfigError(f"output rows up to {rows.max()} for a {P.shape[0]}-dim state")
        keep = x.copy() if self.keep_x is None else (
            _EMPTY if self.keep_x == 0 else x[: self.keep_x].copy())
        if self.marks and (rows.size, keep.size) != (self.marks[0].rows.size,
                                                     self.marks[0].x.size):  # fmt: skip
            # the marks are stacked by ``smooth``: numpy's "inhomogeneous shape" there (a review)
            missing = [name for name, val in (("output_rows", self.output_rows),
                                              ("keep_x", self.keep_x)) if val is None]  # fmt: skip
            raise ConfigError(
                f"RtsRecorder.mark: the state changed size (now {x.size} entries) and the marks "
                f"keep all of it: give {' and '.join(missing)} to smooth a state that changes "
                "size")
        mark = MarkEpoch(int(t_ns), keep, rows, np.zeros((rows.size, 0), np.float32),
                         np.zeros(rows.size), _pack(np.zeros((rows.size,) * 2)))  # fmt: skip
        self.marks.append(mark)
        due = (self._last_chain_ns is None
               or t_ns - self._last_chain_ns >= self.chain_interval_ns)  # fmt: skip
        if due or last:
            self._close_into_chain(int(t_ns), P, last)
            mark.B = np.eye(P.shape[0], dtype=np.float32)[rows]
            mark.chain = len(self.chain) - 1
        else:
            r = rows.size
            self._open.append(_Open(len(self.marks) - 1, False, np.eye(P.shape[0])[rows],
                                    np.zeros(r), np.zeros((r, r))))
        if last:
            self.finished = True

    # ---- internals ------------------------------------------------------------------------
    def _link(self, P_prior: F64, delta: F64 | None) -> None:
        """Compose the gain from the last epoch's posterior to the prior ``P_prior`` at an
        epoch whose update stepped by ``delta`` (None: a mark, no step) into the open epochs."""
        P_prev = self._P_post
        phi = self._phi
        assert P_prev is not None
        if phi is None and (P_prior is P_prev or np.array_equal(P_prior, P_prev)):
            # Same time, nothing in between: G = I, M = 0.
            if delta is not None:
                for o in self._open:
                    o.a += o.B @ delta
            return
        P_prior = np.asarray(P_prior, dtype=float)
        C = P_prev if phi is None else P_prev @ phi.T  # (n_prev, n_now)
        if C.shape[1] != P_prior.shape[0]:
            raise FilterError(
                f"RTS: the map reaches {C.shape[1]} dims, the prior has {P_prior.shape[0]}"
            )
        try:
            # LU on a small matrix: cheaper here than scipy's Cholesky wrappers per epoch.
            GT = np.linalg.solve(P_prior, C.T)
        except np.linalg.LinAlgError:
            GT = np.linalg.lstsq(P_prior, C.T, rcond=None)[0]
        G = GT.T  # (n_prev, n_now)
        M = P_prev - G @ C.T
        M = 0.5 * (M + M.T)
        d = None if delta is None else G @ delta
        for o in self._open:
            BM = o.B @ M
            o.M += BM @ o.B.T
            if d is not None:
                o.a += o.B @ d
            o.B = o.B @ G
        self._phi = None

    def _close_into_chain(self, t_ns: int, P: F64, last: bool) -> None:
        """Store a chain epoch at ``t_ns``: every open epoch is tied to it; a new chain epoch
        opens (the last one keeps its own ``P`` as the smoothed covariance)."""
        k = len(self.chain)
        for o in self._open:
            if o.chain:
                self.chain[o.index] = ChainEpoch(self._chain_t[o.index], o.B, o.a, _pack(o.M))
            else:
                m = self.marks[o.index]
                m.B, m.chain = o.B.astype(np.float32), k
                m.a, m.M_packed = o.a, _pack(o.M).astype(np.float32)
        self._open = []
        self._chain_t.append(t_ns)
        n = P.shape[0]
        if last:
            self.chain.append(ChainEpoch(t_ns, np.zeros((n, 0)), np.zeros(n), _pack(P)))
        else:
            self.chain.append(None)
            self._open.append(_Open(k, True, np.eye(n), np.zeros(n), np.zeros((n, n))))
        self._last_chain_ns = t_ns

    @property
    def nbytes(self) -> int:
        """Bytes held by the stored epochs: their arrays (data and headers, each array once:
        the marks share their rows) and the objects and lists holding them (the arrays' data
        alone said 34-49 % less: a user's probe)."""
        seen: set[int] = set()

        def size(*objs: object) -> int:
            n = 0
            for o in objs:
                if id(o) not in seen:
                    seen.add(id(o))
                    n += sys.getsizeof(o)  # an array owning its data: data and header
            return n

        total = size(self.chain, self.marks, self._chain_t, *self._chain_t)
        for c in self.chain:
            if c is not None:
                total += size(c, c.t_ns, c.B, c.a, c.M_packed)
        for m in self.marks:
            total += size(m, m.t_ns, m.chain, m.x, m.rows, m.B, m.a, m.M_packed)
        for o in self._open:
            total += size(o, o.B, o.a, o.M)
        return total


@dataclass(frozen=True)
class Smoothed:
    """The smoothed marks: ``t_ns`` (N,), forward means ``x`` (N, nx_kept), the smoothed
    tangent corrections ``eps`` (N, r) on ``rows`` (apply with the manifold's retraction) and
    covariances ``P`` (N, r, r). The whole-state epochs: ``chain_t_ns`` (C,), their corrections
    ``chain_eps`` and smoothed variances ``chain_var`` (C lists of (ndx_c,) arrays; ndx_c may
    change where the state was resized)."""

    t_ns: I64
    x: F64
    rows: I64
    eps: F64
    P: F64
    chain_t_ns: I64
    chain_eps: list[F64]
    chain_var: list[F64]


def smooth(recorder: RtsRecorder) -> Smoothed:
    """The backward pass over a finished recording (``recorder.mark(..., last=True)`` done)."""
    if not recorder.finished:
        raise FilterError("smooth() needs a finished recording (mark the last epoch)")
    if recorder.considered:
        raise FilterError("smooth(): the recording holds updates with consider parameters, "
                          "which this RTS pass does not handle (it can end worse than the "
                          "filter)")
    chain = recorder.chain
    n = len(chain)
    eps_c: list[F64] = [np.zeros(0)] * n
    Ps_c: list[F64] = [np.zeros((0, 0))] * n
    for k in range(n - 1, -1, -1):
        c = chain[k]
        assert c is not None
        if k == n - 1 or c.B.shape[1] == 0:
            eps_c[k] = c.a.copy()
            Ps_c[k] = c.M.copy()
            continue
        eps_c[k] = c.a + c.B @ eps_c[k + 1]
        Ps = c.M + c.B @ Ps_c[k + 1] @ c.B.T
        Ps_c[k] = 0.5 * (Ps + Ps.T)
    marks = recorder.marks
    r = marks[0].rows.size if marks else 0
    eps = np.zeros((len(marks), r))
    P = np.zeros((len(marks), r, r))
    for i, m in enumerate(marks):
        B = m.B.astype(float)
        e = m.a + B @ eps_c[m.chain]
        Pm = _unpack(m.M_packed, m.a.size) + B @ Ps_c[m.chain] @ B.T
        eps[i], P[i] = e, 0.5 * (Pm + Pm.T)
    return Smoothed(
        np.array([m.t_ns for m in marks], dtype=np.int64),
        np.array([m.x for m in marks]),
        marks[0].rows.copy() if marks else np.zeros(0, np.int64),
        eps, P, np.array([c.t_ns for c in chain if c is not None], dtype=np.int64), eps_c,
        [np.diag(p).copy() for p in Ps_c],
    )  # fmt: skip
