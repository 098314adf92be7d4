"""Accuracy and consistency figures of an estimated trajectory against ground truth."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from evo import EvoException
from numpy.typing import NDArray

from svains.datasets.types import GroundTruth
from svains.errors import SvainsError
from svains.evaluation.metrics import ate
from svains.geometry.rotation import quat_box_minus, quat_box_plus

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
log = logging.getLogger(__name__)


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


# Fallback order when an alignment is degenerate (a straight or too short trajectory leaves the
# rotation about its own line undetermined and evo raises): drop to fewer degrees of freedom.
_FALLBACK: dict[str, tuple[str, ...]] = {
    "se3": ("se3", "posyaw", "none"),
    "sim3": ("sim3", "se3", "posyaw", "none"),
    "posyaw": ("posyaw", "none"),
    "none": ("none",),
}


def _ate_once(t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str) -> float:
    return float(ate(t_ns, p_est, q_est, t_ns, p_ref, q_ref, align=alignment).rmse)  # type: ignore[arg-type]


def ate_with_fallback(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3"
) -> tuple[float, str]:
    """ATE RMSE (m) and the alignment actually used, reference sampled at ``t_ns`` (N,).

    Tries ``alignment`` first, then fewer degrees of freedom (``_FALLBACK``) when the fit is
    degenerate (evo's ``GeometryException`` on a straight trajectory, too few poses, or a
    non-finite result); never raises for a degenerate geometry.
    """
    for align in _FALLBACK.get(alignment, (alignment, "none")):
        try:
            value = _ate_once(t_ns, p_est, q_est, p_ref, q_ref, align)
        except (EvoException, SvainsError, np.linalg.LinAlgError) as exc:
            log.warning(
                "ATE with %s alignment failed (%s); trying fewer degrees of freedom", align, exc
            )
            continue
        if np.isfinite(value):
            return value, align
    return float(np.sqrt(np.mean(np.sum((p_est - p_ref) ** 2, axis=1)))), "none"


def ate_rmse(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3"
) -> float:
    """Absolute trajectory error RMSE (m) after ``alignment`` (with ``ate_with_fallback``'s
    fallback when it is degenerate), reference sampled at ``t_ns``.

    Computed by ``svains.evaluation.metrics.ate`` (evo), so it equals ``evo_ape``.
    """
    return ate_with_fallback(t_ns, p_est, q_est, p_ref, q_ref, alignment)[0]


def nees_of(e: F64, P: F64) -> F64:
    """Normalised estimation error squared ``e^T P^-1 e`` (N,) of errors (N, d), covariances
    (N, d, d)."""
    return np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])


def nees_series(t_ns: I64, x: F64, P9: F64, gt: GroundTruth) -> tuple[I64, F64]:
    """NEES (9 dof: p, v, attitude) at the logged times inside the ground truth's span."""
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    return np.asarray(t_ns)[inside], nees_of(navigation_errors(x[inside], p, v, q), P9[inside])


def accuracy_report(
    t_ns: I64, x: F64, P9: F64, gt: GroundTruth | None, alignment: str = "se3"
) -> dict[str, Any]:
    """Report keys against ground truth (None values when there is none)."""
    keys = ("ate_rmse_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean")
    out: dict[str, Any] = dict.fromkeys(keys)
    out["alignment"] = alignment
    if gt is None or len(gt.t_ns) < 2:
        return out
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    if inside.sum() < 2:
        return out
    xe = x[inside]
    e = navigation_errors(xe, p, v, q)
    P = P9[inside]
    nees = nees_of(e, P)
    std = np.sqrt(np.einsum("nii->ni", P))
    ate_m, out["alignment"] = ate_with_fallback(
        t_ns[inside], xe[:, 0:3], xe[:, 6:10], p, q, alignment
    )
    out.update(
        ate_rmse_m=ate_m,
        position_rmse_m=float(np.sqrt(np.mean(np.sum(e[:, 0:3] ** 2, axis=1)))),
        velocity_rmse_mps=float(np.sqrt(np.mean(np.sum(e[:, 3:6] ** 2, axis=1)))),
        attitude_rmse_deg=float(np.degrees(np.sqrt(np.mean(np.sum(e[:, 6:9] ** 2, axis=1))))),
        nees_mean=float(nees.mean()),
        nees_dof=9,
        position_within_3sigma=float(np.mean(np.abs(e[:, 0:3]) <= 3.0 * std[:, 0:3])),
        evaluated_states=int(inside.sum()),
    )
    return out


def gps_outage_report(
    t_ns: I64, x: F64, std: F64, gps_t_ns: I64, gt: GroundTruth, min_gap_s: float = 3.0
) -> dict[str, Any]:
    """Position error while GPS is available, and its growth over each GPS outage.

    An outage is a gap longer than ``min_gap_s`` between consecutive GPS fixes. Returns
    ``position_rmse_with_gps_m`` (logged states outside outages) and ``gps_outages``: for each,
    start/end (s from the first state), position error at the start and at the end, its maximum,
    and the filter's 3σ position bound (norm of the 3σ per axis) at the end.
    """
    inside, p, _, _ = interpolate_groundtruth(gt, t_ns)
    t = np.asarray(t_ns)[inside]
    err = np.linalg.norm(p - x[inside, 0:3], axis=1)
    sig3 = 3.0 * np.linalg.norm(std[inside, 0:3], axis=1)
    g = np.asarray(gps_t_ns, dtype=np.int64)
    gaps = np.flatnonzero(np.diff(g) > int(min_gap_s * 1e9))
    in_outage = np.zeros(len(t), dtype=bool)
    outages = []
    for k in gaps:
        a, b = int(g[k]), int(g[k + 1])
        sel = (t >= a) & (t < b)
        if not sel.any():
            continue
        in_outage |= sel
        e = err[sel]
        outages.append(
            {
                "start_s": (a - t_ns[0]) * 1e-9,
                "duration_s": (b - a) * 1e-9,
                "error_start_m": float(e[0]),
                "error_end_m": float(e[-1]),
                "error_max_m": float(e.max()),
                "growth_m": float(e[-1] - e[0]),
                "bound_3sigma_end_m": float(sig3[sel][-1]),
            }
        )
    ok = ~in_outage
    return {
        "position_rmse_with_gps_m": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else None,
        "gps_outages": outages,
    }
