"""The UKF on a linear-Gaussian model equals the Kalman filter; gating; large measurements."""

from __future__ import annotations

import numpy as np
import pytest

from svains.errors import ConfigError, FilterError
from svains.filter import UKF, Euclidean, MerweScaledSigmaPoints, chi2_gate
from svains.filter.ukf import kalman_correction


def _linear_problem(seed: int = 0, n: int = 4, nz: int = 2):
    rng = np.random.default_rng(seed)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    H = rng.normal(size=(nz, n))
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    R = np.diag(rng.uniform(0.1, 0.5, nz))
    x0 = rng.normal(size=n)
    P0 = np.eye(n) * 0.5
    return rng, F, H, Q, R, x0, P0


def test_ukf_equals_kalman_filter_on_a_linear_model() -> None:
    rng, F, H, Q, R, x0, P0 = _linear_problem()
    n = F.shape[0]
    ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n, alpha=0.7), x0, P0)
    x, P = x0.copy(), P0.copy()
    for _ in range(20):
        u = rng.normal(size=n)
        ukf.predict(lambda X, u, dt: X @ F.T + u, u, 0.1, Q)
        x, P = F @ x + u, F @ P @ F.T + Q
        z = rng.normal(size=H.shape[0])
        stats = ukf.update(lambda X: X @ H.T, z, R, name="lin")
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        r = z - H @ x
        assert stats.accepted and stats.nis == pytest.approx(r @ np.linalg.solve(S, r), rel=1e-9)
        x, P = x + K @ r, P - K @ S @ K.T
        np.testing.assert_allclose(ukf.x, x, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(ukf.P, P, rtol=1e-9, atol=1e-10)


def test_woodbury_path_equals_dense_path_for_large_measurements() -> None:
    rng = np.random.default_rng(3)
    n, nz = 6, 400  # nz > 2 * (2n + 1): the diagonal-R update takes the Woodbury path
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    x0 = rng.normal(size=n)
    H = rng.normal(size=(nz, n))
    z = H @ x0 + rng.normal(size=nz)
    Rdiag = rng.uniform(0.5, 2.0, nz)

    def h(X: np.ndarray) -> np.ndarray:
        return np.sin(X) @ H.T  # nonlinear so the sigma-point statistics matter

    a = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    b = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    sa = a.update(h, z, Rdiag)
    sb = b.update(h, z, np.diag(Rdiag))  # full R: dense Cholesky path
    assert sa.nis == pytest.approx(sb.nis, rel=1e-9)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-8, atol=1e-12)


def test_chi_square_gate_rejects_an_outlier_and_leaves_the_state() -> None:
    _, F, H, _, R, x0, P0 = _linear_problem(1)
    n = F.shape[0]
    ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    good = ukf.update(lambda X: X @ H.T, H @ x0 + 0.1, R, gate_probability=0.999, name="g")
    assert good.accepted and good.gate == pytest.approx(chi2_gate(0.999, 2))
    x, P = ukf.x.copy(), ukf.P.copy()
    bad = ukf.update(lambda X: X @ H.T, H @ x0 + 100.0, R, gate_probability=0.999, name="g")
    assert not bad.accepted and bad.nis > bad.gate
    np.testing.assert_array_equal(ukf.x, x)
    np.testing.assert_array_equal(ukf.P, P)


def test_residual_function_wraps_angles() -> None:
    ukf = UKF(Euclidean(1), MerweScaledSigmaPoints(1), np.array([3.1]), np.eye(1) * 0.01)

    def wrap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a - b + np.pi) % (2 * np.pi) - np.pi

    # A heading of -3.1 rad is 0.083 rad from 3.1 rad, not 6.2 rad.
    stats = ukf.update(lambda X: X, np.array([-3.1]), np.array([0.01]), 0.99, wrap)
    assert stats.accepted
    assert abs(wrap(ukf.x, np.array([3.1 + 0.0416]))[0]) < 1e-3


def test_bad_inputs_raise_clear_errors() -> None:
    m, sp = Euclidean(2), MerweScaledSigmaPoints(2)
    with pytest.raises(ConfigError, match="do not match"):
        UKF(m, sp, np.zeros(3), np.eye(2))
    with pytest.raises(ConfigError, match="sigma points for n=3"):
        UKF(m, MerweScaledSigmaPoints(3), np.zeros(2), np.eye(2))
    with pytest.raises(FilterError, match="initial covariance is not positive definite"):
        UKF(m, sp, np.zeros(2), np.diag([1.0, -1.0]))
    ukf = UKF(m, sp, np.zeros(2), np.eye(2))
    with pytest.raises(ConfigError, match="R has shape"):
        ukf.update(lambda X: X, np.zeros(2), np.eye(3))
    with pytest.raises(FilterError, match="non-finite sigma points"):
        ukf.predict(lambda X, u, dt: X * np.nan, None, 0.1, np.zeros(2))
    ukf.P = np.diag([1.0, -2.0])
    with pytest.raises(FilterError, match="sigma-point covariance is not positive definite"):
        ukf.predict(lambda X, u, dt: X, None, 0.1, np.zeros(2))


def test_update_blocks_gates_each_block_and_fuses_the_rest_together() -> None:
    rng, _, H, _, R, x0, P0 = _linear_problem(2, n=4, nz=2)
    n = 4
    H2 = rng.normal(size=(3, n))
    R2 = np.full(3, 0.2)
    z1 = H @ x0 + 0.05
    z2 = H2 @ x0 - 0.05

    def fresh() -> UKF:
        return UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)

    a, b = fresh(), fresh()
    stats = a.update_blocks(
        [(lambda X: X @ H.T, z1, R, None, "one"), (lambda X: X @ H2.T, z2, R2, None, "two")], 0.999
    )
    assert [s.accepted for s in stats] == [True, True]
    HH = np.vstack([H, H2])
    b.update(lambda X: X @ HH.T, np.r_[z1, z2], np.diag(np.r_[np.diag(R), R2]))
    np.testing.assert_allclose(a.x, b.x, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, atol=1e-12)
    # A gross error in block two rejects only block two.
    c, d = fresh(), fresh()
    stats = c.update_blocks(
        [(lambda X: X @ H.T, z1, R, None, "one"), (lambda X: X @ H2.T, z2 + 50, R2, None, "two")],
        0.999,
    )
    assert [s.accepted for s in stats] == [True, False] and stats[1].name == "two"
    # Each block's whitened innovation: L^-1 r with S = H P H^T + R = L L^T (linear: exact).
    for s, Hk, Rk, zk in ((stats[0], H, R, z1), (stats[1], H2, np.diag(R2), z2 + 50)):
        L = np.linalg.cholesky(Hk @ P0 @ Hk.T + Rk)
        assert s.whitened is not None
        np.testing.assert_allclose(s.whitened, np.linalg.solve(L, zk - Hk @ x0), rtol=1e-9)
        np.testing.assert_allclose(s.whitened @ s.whitened, s.nis, rtol=1e-12)
    d.update(lambda X: X @ H.T, z1, R)
    np.testing.assert_allclose(c.x, d.x, atol=1e-12)
    np.testing.assert_allclose(c.P, d.P, atol=1e-12)


def _low_rank_problem(seed: int = 5, n: int = 6, nz: int = 120):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    x0 = rng.normal(size=n)
    H = rng.normal(size=(nz, n))
    z = np.sin(x0) @ H.T + rng.normal(size=nz)
    Rdiag = rng.uniform(0.5, 2.0, nz)
    D = rng.normal(size=(3, nz))  # e.g. one shared 3-vector input's error seen by all rows
    return x0, P0, H, z, Rdiag, D


def test_low_rank_noise_update_equals_the_dense_formula() -> None:
    x0, P0, H, z, Rdiag, D = _low_rank_problem()
    n = x0.size

    def h(X: np.ndarray) -> np.ndarray:
        return np.sin(X) @ H.T

    a = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    b = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    sa = a.update(h, z, Rdiag, R_low_rank=D)  # diagonal + low rank: matrix-inversion lemma
    sb = b.update(h, z, np.diag(Rdiag) + D.T @ D)  # the same noise as one dense matrix
    assert sa.accepted and sb.accepted
    assert sa.nis == pytest.approx(sb.nis, rel=1e-9)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-8, atol=1e-12)
    # ... and it is not a no-op: without D the answer differs.
    c = UKF(Euclidean(n), MerweScaledSigmaPoints(n), x0, P0)
    c.update(h, z, Rdiag)
    assert np.abs(c.x - a.x).max() > 1e-3


def test_kalman_correction_matches_the_textbook_gain() -> None:
    from svains.filter import kalman_correction

    x0, P0, H, z, Rdiag, D = _low_rank_problem(seed=6, nz=40)
    n = x0.size
    points = MerweScaledSigmaPoints(n)
    dX = points.offsets(P0)
    dY = np.sin(x0 + dX) @ H.T
    y = points.Wm @ dY
    dY = dY - y
    r = z - y
    S = dY.T @ (points.Wc[:, None] * dY) + np.diag(Rdiag) + D.T @ D
    Pxz = dX.T @ (points.Wc[:, None] * dY)
    K = Pxz @ np.linalg.inv(S)
    for allow in (True, False):  # Woodbury and dense paths
        dx, nis, dP = kalman_correction(dX, dY, points.Wc, Rdiag, r, D, allow_woodbury=allow)
        np.testing.assert_allclose(dx, K @ r, rtol=1e-9, atol=1e-12)
        assert nis == pytest.approx(r @ np.linalg.solve(S, r), rel=1e-9)
        np.testing.assert_allclose(dP, K @ S @ K.T, rtol=1e-8, atol=1e-12)


def test_low_rank_noise_with_a_wrong_shape_is_rejected() -> None:
    x0, P0, H, z, Rdiag, D = _low_rank_problem()
    ukf = UKF(Euclidean(x0.size), MerweScaledSigmaPoints(x0.size), x0, P0)
    with pytest.raises(ConfigError, match=r"R_low_rank has shape \(120, 3\), expected \(k, 120\)"):
        ukf.update(lambda X: X @ H.T, z, Rdiag, R_low_rank=D.T)


def test_sigma_points_are_reused_until_the_state_changes() -> None:
    x0, P0, *_ = _low_rank_problem()
    ukf = UKF(Euclidean(x0.size), MerweScaledSigmaPoints(x0.size), x0, P0)
    X1, dX1 = ukf.sigma_points()
    X2, _ = ukf.sigma_points()
    assert X2 is X1 and not X1.flags.writeable and not dX1.flags.writeable
    ukf.P = ukf.P * 2.0  # a new covariance: new points, spread by sqrt(2)
    X3, dX3 = ukf.sigma_points()
    assert X3 is not X1
    np.testing.assert_allclose(dX3, np.sqrt(2.0) * dX1, rtol=1e-12, atol=1e-14)
    ukf.x[0] += 1.0  # in-place edits of x are seen too
    X4, _ = ukf.sigma_points()
    np.testing.assert_allclose(X4[:, 0], X3[:, 0] + 1.0, rtol=1e-12)


@pytest.mark.parametrize("probability", [0.9, 0.99, 0.997, 0.9999])
def test_chi2_gate_equals_scipy_stats(probability: float) -> None:
    """The gate is scipy.stats.chi2.ppf, bit for bit, without importing scipy.stats."""
    from scipy.stats import chi2

    for dof in (1, 2, 4, 6, 15, 400, 1600):
        assert chi2_gate(probability, dof) == float(chi2.ppf(probability, dof))


def _duplicated_measurement_ukf() -> UKF:
    """A 3-state filter (variance 1e4 on the first) and its sigma points for ``X[:, [0, 0]]``:
    the same noiseless component twice, an innovation covariance singular to round-off."""
    return UKF(Euclidean(3), MerweScaledSigmaPoints(3, alpha=0.5176), np.zeros(3),
               np.diag([1e4, 1.0, 2.0]))  # fmt: skip


def test_an_innovation_covariance_singular_to_round_off_is_repaired() -> None:
    def twice(X: np.ndarray) -> np.ndarray:
        return X[:, [0, 0]]

    ukf = _duplicated_measurement_ukf()
    X, dX = ukf.sigma_points()
    Wc = ukf.points.Wc
    dY = twice(X) - ukf.points.Wm @ twice(X)
    S = dY.T @ (Wc[:, None] * dY)
    with pytest.raises(np.linalg.LinAlgError):  # what a plain factorisation does with it
        np.linalg.cholesky(0.5 * (S + S.T))
    z = np.array([3.0, 3.0])
    once = _duplicated_measurement_ukf()
    s1 = once.update(lambda X: X[:, :1], z[:1], np.zeros((1, 1)))
    dx, nis, dP = kalman_correction(dX, dY, Wc, np.zeros((2, 2)), z, name="twice")
    np.testing.assert_allclose(dx, once.x, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ukf.P - dP, once.P, rtol=0, atol=1e-6)
    assert nis == pytest.approx(s1.nis, rel=1e-6)
    s2 = ukf.update(twice, z, np.zeros((2, 2)), name="twice")
    assert s2.accepted and s2.nis == pytest.approx(s1.nis, rel=1e-6)
    np.testing.assert_allclose(ukf.x, once.x, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ukf.P, once.P, rtol=0, atol=1e-6)
    blocks = _duplicated_measurement_ukf()
    (s3,) = blocks.update_blocks([(twice, z, np.zeros((2, 2)), None, "twice")])
    assert s3.accepted and s3.nis == pytest.approx(s1.nis, rel=1e-6)
    np.testing.assert_allclose(blocks.x, once.x, rtol=1e-6, atol=1e-9)


def test_an_indefinite_measurement_noise_still_raises() -> None:
    # A front end's covariance with negative variances (not round-off) must stop the update.
    ukf = _duplicated_measurement_ukf()
    R = np.array([[-5e7, 1e9], [1e9, -1e9]])
    with pytest.raises(FilterError, match=r"innovation covariance of vision_lc is not positive "
                       r"definite \(smallest eigenvalue -"):
        ukf.update(lambda X: X[:, :2], np.zeros(2), R, name="vision_lc")
    with pytest.raises(FilterError, match="innovation covariance of vision_lc"):
        ukf.update_blocks([(lambda X: X[:, :2], np.zeros(2), R, None, "vision_lc")])


def test_nis_per_dof_limit_refuses_many_stacked_measurements_without_a_quantile() -> None:
    # 400 measurements of one state, each 1.6 sigma off: NIS/dof ~2.6, refused by the
    # quantile gate (1.2 nz at 0.999), accepted by a limit of 3 per dof, refused by 2.
    n, nz = 2, 400
    rng = np.random.default_rng(3)
    z = 1.6 * np.sign(rng.standard_normal(nz))
    H = np.zeros((nz, n))
    H[:, 0] = 1.0

    def fresh() -> UKF:
        return UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), np.eye(n) * 1e-6)

    def h(X: np.ndarray) -> np.ndarray:
        return X @ H.T

    a = fresh()
    assert not a.update(h, z, np.ones(nz), gate_probability=0.999).accepted
    b = fresh()
    stats = b.update(h, z, np.ones(nz), max_nis_per_dof=3.0)
    assert stats.accepted and 2.0 < stats.nis / nz < 3.0 and stats.gate == 3.0 * nz
    c = fresh()
    x_before = c.x.copy()
    assert not c.update(h, z, np.ones(nz), 0.999999, max_nis_per_dof=2.0).accepted
    np.testing.assert_array_equal(c.x, x_before)
    d = fresh()  # the iterated path takes the same threshold
    assert not d.update(h, z, np.ones(nz), max_nis_per_dof=2.0, iterations=2).accepted


def test_update_blocks_refuses_a_block_nearer_its_suspected_offset() -> None:
    """``offsets``: a block inside its gate is still refused when its innovation fits the
    offset its sensor is suspected of better than zero (a GPS jump, with the filter's spread
    grown until the gate passes it); nearer zero it is fused as without the offset; other
    blocks and other layouts are untouched."""
    n = 3
    P0 = np.eye(n) * 400.0  # 20 m per axis: a 30 m offset passes the 0.999 gate (NIS 2.25)
    R = np.full(n, 1.0)
    d = np.array([30.0, 0.0, 0.0])

    def block(z: np.ndarray, name: str = "gps") -> tuple:  # type: ignore[type-arg]
        return (lambda X: X, z, R, None, name)

    def fresh() -> UKF:
        return UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P0)

    a = fresh()
    (s,) = a.update_blocks([block(np.array([25.0, 0.0, 0.0]))], 0.999, {"gps": d})
    assert s.nis < s.gate and not s.accepted and s.offset_refused
    np.testing.assert_array_equal(a.x, np.zeros(n))  # nothing fused
    np.testing.assert_allclose(s.residual, [25.0, 0.0, 0.0], atol=1e-9)
    b, c = fresh(), fresh()
    (s,) = b.update_blocks([block(np.array([12.0, 0.0, 0.0]))], 0.999, {"gps": d})
    assert s.accepted and not s.offset_refused
    c.update_blocks([block(np.array([12.0, 0.0, 0.0]))], 0.999)
    np.testing.assert_allclose(b.x, c.x)
    # another block's name, or an offset of another size: no test
    for offsets in ({"other": d}, {"gps": np.zeros(6)}):
        (s,) = fresh().update_blocks([block(np.array([25.0, 0.0, 0.0]))], 0.999, offsets)
        assert s.accepted and not s.offset_refused


def test_the_last_gain_and_innovation_solve_are_the_same_on_both_paths() -> None:
    """``UKF.last_gain_T`` (K^T) and ``last_innovation_solve`` (S⁻¹ r), which noise-correlation
    callers read, agree between the Woodbury path (diagonal R, nz >> S) and the dense one, and
    equal the textbook K and S⁻¹ r."""
    rng = np.random.default_rng(4)
    n, nz = 4, 200
    H = rng.normal(size=(nz, n))
    x0, P0 = rng.normal(size=n), np.diag(rng.uniform(0.1, 1.0, n))
    R, z = rng.uniform(0.5, 1.0, nz), rng.normal(size=nz)
    fast = UKF(Euclidean(n), MerweScaledSigmaPoints(n, alpha=1.0), x0, P0)
    dense = UKF(Euclidean(n), MerweScaledSigmaPoints(n, alpha=1.0), x0, P0)
    fast.update(lambda X: X @ H.T, z, R)
    dense.update(lambda X: X @ H.T, z, np.diag(R))
    S = H @ P0 @ H.T + np.diag(R)
    for ukf in (fast, dense):
        assert ukf.last_gain_T is not None and ukf.last_innovation_solve is not None
        np.testing.assert_allclose(ukf.last_gain_T, np.linalg.solve(S, H @ P0), atol=1e-10)
        np.testing.assert_allclose(ukf.last_innovation_solve, np.linalg.solve(S, z - H @ x0),
                                   atol=1e-9)  # fmt: skip


def test_a_linear_update_with_a_shared_error_is_the_augmented_kalman_update() -> None:
    """``update_linear`` with noise sharing an error with the state equals the Kalman update of
    the state augmented by that error, marginalised: state e (n) and a nuisance d (1) jointly
    Gaussian, r = H e - s d + n. Without the shared term it is the textbook update; a refused
    innovation leaves the state; a covariance not positive definite is named."""
    rng = np.random.default_rng(3)
    n, nz = 5, 2
    A = rng.normal(size=(n + 1, n + 1))
    Paug = A @ A.T + 0.1 * np.eye(n + 1)  # [e, d]
    P, c, var_d = Paug[:n, :n], Paug[:n, n], Paug[n, n]
    H, s = rng.normal(size=(nz, n)), rng.normal(size=nz)
    Rn = np.diag([0.3, 0.5])
    r = rng.normal(size=nz)
    # the augmented update: r = [H, -s] [e; d] + n
    Ha = np.hstack([H, -s[:, None]])
    S = Ha @ Paug @ Ha.T + Rn
    K = Paug @ Ha.T @ np.linalg.inv(S)
    x_aug = K @ r
    P_aug = Paug - K @ S @ K.T
    ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P.copy())
    # v = n - s d: Cov(e, v) = -c sᵀ, Cov(v) = Rn + var_d s sᵀ
    stats = ukf.update_linear(H, r, Rn + var_d * np.outer(s, s), -np.outer(c, s))
    assert stats.accepted and stats.dof == nz
    np.testing.assert_allclose(ukf.x, x_aug[:n], atol=1e-12)
    np.testing.assert_allclose(ukf.P, P_aug[:n, :n], atol=1e-12)
    assert stats.nis == pytest.approx(float(r @ np.linalg.solve(S, r)))
    plain = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P.copy())
    plain.update_linear(H, r, Rn)
    K0 = P @ H.T @ np.linalg.inv(H @ P @ H.T + Rn)
    np.testing.assert_allclose(plain.x, K0 @ r, atol=1e-12)
    far = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P.copy())
    refused = far.update_linear(H, 1e3 * r, Rn, gate_probability=0.999)
    assert not refused.accepted and np.all(far.x == 0.0) and np.all(far.P == P)
    with pytest.raises(FilterError, match="gps_held: innovation covariance not positive"):
        far.update_linear(H, r, -1e6 * np.eye(nz), name="gps_held")
