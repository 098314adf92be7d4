"""Ground-truth association of a run's logged states: truth at the state times, errors, NEES.

Pure numpy, no alignment and no trajectory metrics: the accuracy keys of ``report.json`` (ATE
equal to evo's, alignment-aware RMSE) are computed in :mod:`svains.evaluation.accuracy`, above the
navigation layer.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.geometry.rotation import quat_box_minus, quat_box_plus
from svains.sensors.types import GroundTruth

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def interpolate_groundtruth(gt: GroundTruth, t_ns: I64) -> tuple[NDArray[np.bool_], F64, F64, F64]:
    """Ground truth at ``t_ns`` (N,): mask of times inside its span, p (M,3), v (M,3), q (M,4)."""
    t = np.asarray(t_ns, dtype=np.int64)
    inside = (t >= gt.t_ns[0]) & (t <= gt.t_ns[-1])
    ti = t[inside]
    j = np.clip(np.searchsorted(gt.t_ns, ti), 1, len(gt.t_ns) - 1)
    s = ((ti - gt.t_ns[j - 1]) / np.maximum(1, gt.t_ns[j] - gt.t_ns[j - 1]))[:, None]
    p = (1 - s) * gt.p_W_B[j - 1] + s * gt.p_W_B[j]
    v = (1 - s) * gt.v_W_B[j - 1] + s * gt.v_W_B[j]
    q0 = gt.q_W_B_wxyz[j - 1]
    q = quat_box_plus(q0, s * quat_box_minus(gt.q_W_B_wxyz[j], q0))
    return inside, p, v, q


def navigation_errors(x: F64, p_gt: F64, v_gt: F64, q_gt: F64) -> F64:
    """Error ``truth ⊟ estimate`` (N, 9): position, velocity, body attitude δθ (rad)."""
    e = np.empty((x.shape[0], 9))
    e[:, 0:3] = p_gt - x[:, 0:3]
    e[:, 3:6] = v_gt - x[:, 3:6]
    e[:, 6:9] = quat_box_minus(q_gt, x[:, 6:10])
    return e


def nees_of(e: F64, P: F64) -> F64:
    """Normalised estimation error squared ``e^T P^-1 e`` (N,) of errors (N, d), covariances
    (N, d, d)."""
    return np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])


def nees_series(t_ns: I64, x: F64, P9: F64, gt: GroundTruth) -> tuple[I64, F64]:
    """NEES (9 dof: p, v, attitude) at the logged times inside the ground truth's span, in the
    estimate's own world frame (no alignment)."""
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    return np.asarray(t_ns)[inside], nees_of(navigation_errors(x[inside], p, v, q), P9[inside])
