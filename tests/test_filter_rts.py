"""The recorded RTS smoother (``filter.rts``) against the exact linear-Gaussian smoother.

The oracle is the batch solution: for a linear-Gaussian model the smoothed mean and covariance
of every state are the mean and the diagonal blocks of the joint posterior over all states,
one least-squares problem. The model is a 1-D constant-velocity track with position fixes and
relative-position measurements against a pose clone (the filter augments a copy of the position
at each "frame" and measures the motion since the previous one, as the vision models do).
"""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError, FilterError
from svains.filter import UKF, Euclidean, MerweScaledSigmaPoints
from svains.filter.rts import RtsRecorder, smooth

DT = 0.1
F = np.array([[1.0, DT], [0.0, 1.0]])
Q = np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]) * 0.04
R_ABS = 0.5**2
R_REL = 0.05**2
P0 = np.diag([1.0, 0.25])
T = 40
FIX_STEPS = {0, 9, 10, 25, 39}  # position fixes (a GPS outage between 10 and 25)
FRAME_EVERY = 3  # a relative measurement against the clone every 3 steps


def _data(seed: int) -> tuple[np.ndarray, dict[int, float], dict[int, float]]:
    rng = np.random.default_rng(seed)
    x = np.zeros((T + 1, 2))
    x[0] = rng.multivariate_normal([0.0, 1.0], P0)
    for t in range(T):
        x[t + 1] = F @ x[t] + rng.multivariate_normal(np.zeros(2), Q)
    fixes = {t: x[t, 0] + rng.normal(0.0, np.sqrt(R_ABS)) for t in FIX_STEPS}
    frames = range(FRAME_EVERY, T + 1, FRAME_EVERY)
    rel = {t: x[t, 0] - x[t - FRAME_EVERY, 0] + rng.normal(0.0, np.sqrt(R_REL)) for t in frames}
    return x, fixes, rel


def _batch(fixes: dict[int, float], rel: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
    """Joint posterior over x_0..x_T: means (T+1, 2), covariances (T+1, 2, 2)."""
    n = 2 * (T + 1)
    L = np.zeros((n, n))
    eta = np.zeros(n)
    def add(J: np.ndarray, r_inv: np.ndarray, z: np.ndarray) -> None:
        nonlocal L, eta
        L += J.T @ r_inv @ J
        eta += J.T @ r_inv @ z
    J = np.zeros((2, n)); J[:, 0:2] = np.eye(2)  # noqa: E702
    add(J, np.linalg.inv(P0), np.array([0.0, 1.0]))
    for t in range(T):
        J = np.zeros((2, n))
        J[:, 2 * t + 2:2 * t + 4] = np.eye(2)
        J[:, 2 * t:2 * t + 2] = -F
        add(J, np.linalg.inv(Q), np.zeros(2))
    for t, z in fixes.items():
        J = np.zeros((1, n)); J[0, 2 * t] = 1.0  # noqa: E702
        add(J, np.array([[1 / R_ABS]]), np.array([z]))
    for t, z in rel.items():
        J = np.zeros((1, n)); J[0, 2 * t] = 1.0; J[0, 2 * (t - FRAME_EVERY)] = -1.0  # noqa: E702
        add(J, np.array([[1 / R_REL]]), np.array([z]))
    cov = np.linalg.inv(L)
    mean = cov @ eta
    return mean.reshape(T + 1, 2), np.array([cov[2 * t:2 * t + 2, 2 * t:2 * t + 2]
                                             for t in range(T + 1)])


def _run(fixes: dict[int, float], rel: dict[int, float], recorder: RtsRecorder,
         reset_at: int | None = None, until: int = T) -> list[tuple[np.ndarray, np.ndarray]]:
    """The filter over the data (two predictions per step), a mark after every step;
    returns the forward (x, P) of the navigation block at each mark."""
    ukf = UKF(Euclidean(2), MerweScaledSigmaPoints(2, 0.5176, 2.0, 0.0), np.array([0.0, 1.0]), P0)
    ukf.recorder = recorder
    recorder.start(ukf.x, ukf.P)
    forward = []
    half = np.array([[1.0, DT / 2], [0.0, 1.0]])

    def f(X: np.ndarray, u: object, dt: float) -> np.ndarray:
        Y = X.copy()
        Y[:, :2] = X[:, :2] @ half.T
        return Y

    def mark(t: int) -> None:
        recorder.mark(t, ukf.x, ukf.P, last=t == until)
        forward.append((ukf.x[:2].copy(), ukf.P[:2, :2].copy()))

    for t in range(until + 1):
        if t > 0:
            n = ukf.P.shape[0]
            Qh = np.zeros((n, n))
            # Two half steps of the same white-acceleration model compose to F and Q exactly.
            Qh[:2, :2] = np.array([[DT**3 / 24, DT**2 / 8], [DT**2 / 8, DT / 2]]) * 0.04
            ukf.predict(f, None, 0.0, Qh)
            ukf.predict(f, None, 0.0, Qh)
        if reset_at is not None and t == reset_at:
            x = ukf.x.copy()
            x[0] += 3.0  # a reset moves the mean behind the filter's back
            ukf.x = x
        if t in rel:
            ukf.update(lambda X: X[:, 0:1] - X[:, 2:3], np.array([rel[t]]), np.array([R_REL]))
        if t in fixes:
            # Two blocks at once (one sigma-point draw) to cover update_blocks.
            ukf.update_blocks([(lambda X: X[:, 0:1], np.array([fixes[t]]), np.array([R_ABS]),
                                None, "fix")])  # fmt: skip
        if t % FRAME_EVERY == 0:
            # Drop the old clone, add a copy of the position (the vision clones' cycle).
            n = ukf.P.shape[0]
            S = np.zeros((3, n))
            S[0, 0] = S[1, 1] = S[2, 0] = 1.0
            x = S @ ukf.x
            P = S @ ukf.P @ S.T
            P[2, 2] += 1e-12
            ukf.resize(Euclidean(3), x, P, transform=S)
        mark(t)
    return forward


@pytest.mark.parametrize("interval", [1, 4, 1000])
def test_smoother_equals_the_batch_solution(interval: int) -> None:
    _, fixes, rel = _data(3)
    mean, cov = _batch(fixes, rel)
    rec = RtsRecorder(chain_interval_ns=interval)
    forward = _run(fixes, rel, rec)
    s = smooth(rec)
    assert s.t_ns.tolist() == list(range(T + 1))
    xs = s.x[:, :2] + s.eps[:, :2]
    # Marks between whole-state epochs keep their gain in float32 (rtol 6e-8).
    np.testing.assert_allclose(xs, mean, atol=1e-7)
    np.testing.assert_allclose(s.P[:, :2, :2], cov, atol=1e-7)
    # The last epoch is the filter's own; every smoothed variance is at most the forward one.
    np.testing.assert_allclose(xs[-1], forward[-1][0], atol=1e-12)
    for (_, Pf), Ps in zip(forward, s.P[:, :2, :2], strict=True):
        assert np.all(np.linalg.eigvalsh(Pf - Ps) > -1e-7)  # float32 gains at marks
    # Inside the outage the fix after it pins the position down (0.050 against 0.085 m²).
    assert s.P[17, 0, 0] < 0.7 * forward[17][1][0, 0]


def test_rows_kept_and_memory() -> None:
    _, fixes, rel = _data(4)
    mean, cov = _batch(fixes, rel)
    rec = RtsRecorder(output_rows=np.array([0]), keep_x=1, chain_interval_ns=10)
    _run(fixes, rel, rec)
    s = smooth(rec)
    assert s.eps.shape == (T + 1, 1) and s.x.shape == (T + 1, 1)
    np.testing.assert_allclose(s.x[:, 0] + s.eps[:, 0], mean[:, 0], atol=1e-7)
    np.testing.assert_allclose(s.P[:, 0, 0], cov[:, 0, 0], atol=1e-7)
    full = RtsRecorder(chain_interval_ns=10)
    _run(fixes, rel, full)
    assert 0 < rec.nbytes < full.nbytes


def test_a_reset_cuts_the_chain() -> None:
    """Epochs before a reset are smoothed with the data up to it only."""
    _, fixes, rel = _data(5)
    cut = RtsRecorder(chain_interval_ns=3)
    _run(fixes, rel, cut, reset_at=20)
    assert cut.cuts == 1
    upto = RtsRecorder(chain_interval_ns=3)
    _run(fixes, rel, upto, until=19)
    a, b = smooth(cut), smooth(upto)
    np.testing.assert_allclose(a.eps[:20], b.eps, atol=1e-7)
    np.testing.assert_allclose(a.P[:20], b.P, atol=1e-7)


def test_misuse_is_refused() -> None:
    rec = RtsRecorder()
    with pytest.raises(FilterError, match="before start"):
        rec.mark(0, np.zeros(2), np.eye(2))
    with pytest.raises(FilterError, match="finished recording"):
        smooth(rec)
    with pytest.raises(ConfigError, match="chain_interval_ns must be positive"):
        RtsRecorder(chain_interval_ns=0)
    rec.start(np.zeros(2), np.eye(2))
    rec.mark(0, np.zeros(2), np.eye(2), last=True)
    with pytest.raises(FilterError, match="after the last epoch"):
        rec.mark(1, np.zeros(2), np.eye(2))
    # marks that keep the whole state, which then grows by a clone: refused at the mark, not
    # numpy's "inhomogeneous shape" in smooth() (a review); fixed rows and means smooth it
    for rows, keep in ((None, None), (np.arange(2), 2)):
        rec = RtsRecorder(output_rows=rows, keep_x=keep)
        rec.start(np.zeros(2), np.eye(2))
        rec.mark(0, np.zeros(2), np.eye(2))
        T = np.vstack([np.eye(2), np.eye(2)[:1]])
        rec.resized(np.zeros(2), np.eye(2), T, np.zeros(3), T @ T.T)
        if rows is None:
            with pytest.raises(ConfigError, match=r"changed size \(now 3 entries\).*give "
                                                  "output_rows and keep_x"):  # fmt: skip
                rec.mark(1, np.zeros(3), T @ T.T, last=True)
        else:
            rec.mark(1, np.zeros(3), T @ T.T, last=True)
            assert smooth(rec).P.shape == (2, 2, 2)


def test_the_memory_said_is_the_memory_held() -> None:
    """``nbytes`` against what the allocator holds for a recording (tracemalloc): the arrays'
    data alone said 34-49 % less than a real run's history (a user's probe)."""
    import tracemalloc

    n = 12
    rng = np.random.default_rng(3)
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        rec = RtsRecorder(np.arange(9), 0, chain_interval_ns=10)
        rec.start(np.zeros(n), P)
        for t in range(1, 2001):
            rec.predicted(np.zeros(n), P, np.eye(n), np.zeros(n))
            rec.mark(t, np.zeros(n), P + 0.01 * t * np.eye(n), last=t == 2000)
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert rec.nbytes == pytest.approx(held, rel=0.05)
    data = sum(m.B.nbytes + m.a.nbytes + m.M_packed.nbytes + m.x.nbytes for m in rec.marks)
    data += sum(c.B.nbytes + c.a.nbytes + c.M_packed.nbytes for c in rec.chain if c)
    assert held > 1.3 * data  # the arrays' data alone, as it was counted
