"""Navigation-state manifold: box-plus/minus inverse, sigma-point mean/cov, fast kernels."""

from __future__ import annotations

import numpy as np
import pytest

from svains.filter import MerweScaledSigmaPoints
from svains.geometry import rotation as rot
from svains.models import _quat
from svains.models.manifold import NavManifold
from svains.models.state import BIASED, PAPER, StateLayout


def _state(rng: np.random.Generator, layout: StateLayout) -> np.ndarray:
    x = rng.normal(size=layout.nx)
    x[6:10] = rot.quat_normalize(x[6:10])
    return x


@pytest.mark.parametrize("layout", [PAPER, BIASED])
def test_local_inverts_retract(layout: StateLayout) -> None:
    rng = np.random.default_rng(5)
    m = NavManifold(layout)
    X = np.stack([_state(rng, layout) for _ in range(7)])
    dX = rng.normal(scale=0.5, size=(7, layout.ndx))
    for x_ref in X:
        Y = m.retract(np.broadcast_to(x_ref, X.shape), dX)
        np.testing.assert_allclose(m.local(Y, x_ref), dX, atol=1e-12)


@pytest.mark.parametrize("layout", [PAPER, BIASED])
def test_sigma_points_on_the_manifold_reproduce_mean_and_covariance(layout: StateLayout) -> None:
    rng = np.random.default_rng(6)
    m = NavManifold(layout)
    sp = MerweScaledSigmaPoints(layout.ndx)
    A = rng.normal(size=(layout.ndx, layout.ndx)) * 0.05
    P = A @ A.T + 1e-4 * np.eye(layout.ndx)
    x = _state(rng, layout)
    X = m.retract(np.broadcast_to(x, (sp.num_points, layout.nx)), sp.offsets(P))
    mean = m.mean(X, sp.Wm)
    np.testing.assert_allclose(m.local(mean[None], x)[0], 0.0, atol=1e-12)
    d = m.local(X, mean)
    np.testing.assert_allclose((d * sp.Wc[:, None]).T @ d, P, atol=1e-12)


def test_quaternion_mean_handles_sign_flips() -> None:
    m = NavManifold(PAPER)
    rng = np.random.default_rng(7)
    x = _state(rng, PAPER)
    X = m.retract(
        np.tile(x, (3, 1)),
        np.array(
            [[0] * 12, [0] * 6 + [0.1, 0, 0] + [0] * 3, [0] * 6 + [-0.1, 0, 0] + [0] * 3], float
        ),
    )
    X[1, 6:10] *= -1.0  # same rotation, other hemisphere
    mean = m.mean(X, np.array([0.0, 0.5, 0.5]))
    np.testing.assert_allclose(np.abs(mean[6:10] @ x[6:10]), 1.0, atol=1e-12)


def test_fast_quaternion_kernels_match_the_reference_helpers() -> None:
    rng = np.random.default_rng(8)
    p = rot.quat_normalize(rng.normal(size=(5, 4)))
    q = rot.quat_normalize(rng.normal(size=(5, 4)))
    v = rng.normal(size=(5, 3))
    th = rng.normal(size=(5, 3))
    th[0] = 1e-9  # small-angle branches
    np.testing.assert_allclose(_quat.qmul(p.T, q.T).T, rot.quat_multiply(p, q), atol=1e-15)
    np.testing.assert_allclose(_quat.qexp(th.T).T, rot.quat_exp(th), atol=1e-15)
    np.testing.assert_allclose(_quat.qlog(q.T).T, rot.quat_log(q), atol=1e-12)
    np.testing.assert_allclose(_quat.qlog(_quat.qexp(th.T)).T, th, atol=1e-12)
    np.testing.assert_allclose(_quat.qrot(q.T, v.T).T, rot.quat_rotate(q, v), atol=1e-14)
    np.testing.assert_allclose(_quat.cross(p[:, 1:].T, v.T).T, np.cross(p[:, 1:], v), atol=1e-15)
    np.testing.assert_allclose(_quat.left_matrix(p[0]) @ q[1], rot.quat_multiply(p[0], q[1]))
