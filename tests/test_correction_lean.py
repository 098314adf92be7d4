"""``whitened_correction``: an update's correction whitened by the covariance it removed is
white and unit on a linear-Gaussian filter (the bias test of vision updates rests on it)."""

from __future__ import annotations

import numpy as np

from svains.filter import UKF, Euclidean, MerweScaledSigmaPoints
from svains.navigation.fault_handling import LEAN_ROWS, whitened_correction


def _problem(seed: int) -> tuple[np.random.Generator, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n, nz = 12, 8  # at least 6: the correction K r has rank nz
    A = rng.normal(size=(n, n))
    P0 = A @ A.T / n + 0.1 * np.eye(n)
    H = rng.normal(size=(nz, n))
    R = np.diag(rng.uniform(0.2, 1.0, nz))
    return rng, P0, H, R


def test_the_whitened_correction_is_white_and_unit_and_equals_its_formula() -> None:
    rng, P0, H, R = _problem(0)
    n = P0.shape[0]
    W = []
    for k in range(3000):
        x_true = rng.multivariate_normal(np.zeros(n), P0)
        z = H @ x_true + rng.multivariate_normal(np.zeros(H.shape[0]), R)
        ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P0.copy())
        ukf.update(lambda X: X @ H.T, z, R)
        w = whitened_correction(ukf, np.zeros(n), P0[np.ix_(LEAN_ROWS, LEAN_ROWS)], LEAN_ROWS)
        assert w is not None and w.shape == (6,)
        if k == 0:  # the Kalman filter's own correction K r, whitened by K S K^T
            S = H @ P0 @ H.T + R
            K = P0 @ H.T @ np.linalg.inv(S)
            rows = np.ix_(LEAN_ROWS, LEAN_ROWS)
            L = np.linalg.cholesky((K @ S @ K.T)[rows])
            np.testing.assert_allclose(w, np.linalg.solve(L, (K @ z)[LEAN_ROWS]), rtol=1e-6)
        W.append(w)
    W = np.array(W)
    np.testing.assert_allclose(W.mean(axis=0), 0.0, atol=0.06)  # 3000 draws: 3 sigma 0.055
    np.testing.assert_allclose(np.cov(W.T), np.eye(6), atol=0.09)


def test_no_whitened_correction_for_unobserved_rows_or_a_state_that_changed_size() -> None:
    rng, P0, H, R = _problem(1)
    n = P0.shape[0]
    P0[:9, 9:] = P0[9:, :9] = 0.0  # rows 3-8 independent of what is measured
    H[:, :9] = 0.0
    ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P0.copy())
    ukf.update(lambda X: X @ H.T, rng.normal(size=H.shape[0]), R)
    assert whitened_correction(ukf, np.zeros(n), P0[np.ix_(LEAN_ROWS, LEAN_ROWS)],
                               LEAN_ROWS) is None  # fmt: skip
    ukf = UKF(Euclidean(n), MerweScaledSigmaPoints(n), np.zeros(n), P0.copy())
    assert whitened_correction(ukf, np.zeros(n + 1), np.eye(6), LEAN_ROWS) is None
