"""Accuracy and consistency keys of ``report.json``: a run's estimates against ground truth.

The ATE goes through evo (:func:`svains.evaluation.metrics.ate`, so it equals ``evo_ape``). The
per-state errors (position, velocity, attitude RMSE, NEES) are taken after ``errors_alignment``:
``none`` when the run's world frame is the ground truth's (initialised from it, or GPS fixes it),
otherwise the alignment of the degrees of freedom the run cannot observe (``posyaw`` for an
inertial or visual-inertial filter: yaw about the up axis and translation, the usual VIO
convention). That yaw is fitted on positions and headings
(:func:`svains.evaluation.alignment.align_posyaw_poses`), so it stays determined when the vehicle
barely moves. The covariance is rotated with the states, so the NEES stays consistent.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from evo import EvoException
from numpy.typing import ArrayLike, NDArray

from svains.datasets.types import GroundTruth
from svains.errors import ConfigError, SvainsError
from svains.evaluation.alignment import align_posyaw_poses
from svains.evaluation.metrics import AteResult, ate
from svains.geometry.rotation import quat_multiply, quat_to_rotmat, rotmat_to_quat
from svains.navigation.report import interpolate_groundtruth, navigation_errors, nees_of

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
log = logging.getLogger(__name__)

# Fallback order when an alignment is degenerate (a straight or too short trajectory leaves the
# rotation about its own line undetermined and evo raises): drop to fewer degrees of freedom.
_FALLBACK: dict[str, tuple[str, ...]] = {
    "se3": ("se3", "posyaw", "none"),
    "sim3": ("sim3", "se3", "posyaw", "none"),
    "posyaw": ("posyaw", "none"),
    "none": ("none",),
}
# Alignments that keep metric scale, so states and covariances can be mapped with (R, t).
ERROR_ALIGNMENTS: tuple[str, ...] = ("none", "posyaw", "se3")


def ate_result_with_fallback(
    t_ns: I64,
    p_est: F64,
    q_est: F64,
    p_ref: F64,
    q_ref: F64,
    alignment: str = "se3",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> AteResult | None:
    """evo ATE of an estimate against a reference sampled at the same ``t_ns`` (N,), with
    ``alignment`` or, when that fit is degenerate (evo's ``GeometryException`` on a straight
    trajectory, too few poses, a non-finite result), fewer degrees of freedom (``_FALLBACK``).
    ``None`` when even ``none`` fails; never raises for a degenerate geometry."""
    for align in _FALLBACK.get(alignment, (alignment, "none")):
        try:
            res = ate(t_ns, p_est, q_est, t_ns, p_ref, q_ref, align=align, up_W=up_W)  # type: ignore[arg-type]
        except (EvoException, SvainsError, np.linalg.LinAlgError) as exc:
            log.warning(
                "ATE with %s alignment failed (%s); trying fewer degrees of freedom", align, exc
            )
            continue
        if np.isfinite(res.rmse):
            return res
    return None


def ate_with_fallback(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3"
) -> tuple[float, str]:
    """ATE RMSE (m) and the alignment actually used (see :func:`ate_result_with_fallback`);
    the unaligned RMSE when every alignment fails."""
    res = ate_result_with_fallback(t_ns, p_est, q_est, p_ref, q_ref, alignment)
    if res is None:
        return float(np.sqrt(np.mean(np.sum((p_est - p_ref) ** 2, axis=1)))), "none"
    return res.rmse, res.alignment


def ate_rmse(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3"
) -> float:
    """Absolute trajectory error RMSE (m) after ``alignment`` (with ``ate_with_fallback``'s
    fallback when it is degenerate), reference sampled at ``t_ns``; equals ``evo_ape``."""
    return ate_with_fallback(t_ns, p_est, q_est, p_ref, q_ref, alignment)[0]


def align_states(x: F64, P9: F64, T_Wref_West: F64) -> tuple[F64, F64]:
    """States (N, nx) and (p, v, δθ) covariances (N, 9, 9) mapped into the reference world by
    the rigid transform ``T_Wref_West`` (4, 4): ``p' = R p + t``, ``v' = R v``, ``q' = q_R ⊗ q``.

    The attitude error is local (body axes, ``R = R̂ Exp(δθ_B)``), so its covariance is unchanged;
    position and velocity covariances (and their cross terms) rotate with ``R``.
    """
    R = np.asarray(T_Wref_West, float)[:3, :3]
    t = np.asarray(T_Wref_West, float)[:3, 3]
    xa = np.array(x, dtype=float, copy=True)
    xa[:, 0:3] = x[:, 0:3] @ R.T + t
    xa[:, 3:6] = x[:, 3:6] @ R.T
    xa[:, 6:10] = quat_multiply(rotmat_to_quat(R)[None, :], x[:, 6:10])
    J = np.eye(9)
    J[0:3, 0:3] = R
    J[3:6, 3:6] = R
    return xa, J @ P9 @ J.T


def _aligned(
    t_in: I64, xe: F64, P: F64, p: F64, q: F64, errors_alignment: str, up_W: ArrayLike
) -> tuple[F64, F64, str]:
    """States (N, nx) and covariances (N, 9, 9) after ``errors_alignment`` against the reference
    ``p``, ``q`` at ``t_in``, and the alignment used (``se3`` falls back when degenerate)."""
    if errors_alignment == "posyaw":
        # Positions and headings: a resting vehicle's positions leave the yaw undetermined.
        T = align_posyaw_poses(xe[:, 0:3], quat_to_rotmat(xe[:, 6:10]), p, quat_to_rotmat(q), up_W)
        xe, P = align_states(xe, P, T)
    elif errors_alignment == "se3":
        fit = ate_result_with_fallback(t_in, xe[:, 0:3], xe[:, 6:10], p, q, "se3", up_W)
        if fit is None:
            return xe, P, "none"
        xe, P = align_states(xe, P, fit.T_align)
        return xe, P, fit.alignment
    return xe, P, errors_alignment


@dataclass(frozen=True)
class StateErrors:
    """Per-state errors against ground truth after an alignment: ``t_ns`` (N,) logged times
    inside the ground truth's span, ``e`` (N, 9) ``truth ⊟ estimate`` of (p m, v m/s, δθ rad),
    ``P9`` (N, 9, 9) covariances mapped by the same alignment, ``alignment`` the one used."""

    t_ns: I64
    e: F64
    P9: F64
    alignment: str

    @property
    def nees(self) -> F64:
        """NEES (N,) of (p, v, δθ), 9 dof."""
        return nees_of(self.e, self.P9)


def state_errors(
    t_ns: I64,
    x: F64,
    P9: F64,
    gt: GroundTruth | None,
    errors_alignment: str = "none",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> StateErrors | None:
    """Errors of states ``x`` (T, nx) with covariances ``P9`` (T, 9, 9) at ``t_ns`` (T,) after
    ``errors_alignment`` (``none``, ``posyaw`` about ``up_W`` or ``se3``); ``None`` without
    ground truth or with fewer than 2 states inside its span."""
    if errors_alignment not in ERROR_ALIGNMENTS:
        raise ConfigError(
            f"unknown errors alignment {errors_alignment!r} (one of {', '.join(ERROR_ALIGNMENTS)})"
        )
    if gt is None or len(gt.t_ns) < 2:
        return None
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    if inside.sum() < 2:
        return None
    t_in = np.asarray(t_ns)[inside]
    xe, P, used = _aligned(t_in, x[inside], P9[inside], p, q, errors_alignment, up_W)
    return StateErrors(t_in, navigation_errors(xe, p, v, q), P, used)


def accuracy_report(
    t_ns: I64,
    x: F64,
    P9: F64,
    gt: GroundTruth | None,
    alignment: str = "se3",
    errors_alignment: str = "none",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> dict[str, Any]:
    """Report keys against ground truth (None values when there is none).

    ``ate_rmse_m`` after ``alignment`` (key ``alignment``: the one used after fallback);
    position/velocity/attitude RMSE, NEES and the 3σ coverage after ``errors_alignment``
    (``none``, ``posyaw`` about ``up_W`` or ``se3``; key ``errors_alignment``: the one used),
    from :func:`state_errors`.
    """
    keys = ("ate_rmse_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean")
    out: dict[str, Any] = dict.fromkeys(keys)
    out["alignment"] = alignment
    out["errors_alignment"] = errors_alignment
    errs = state_errors(t_ns, x, P9, gt, errors_alignment, up_W)
    if errs is None:
        return out
    assert gt is not None  # state_errors returns None without ground truth
    inside, p, _, q = interpolate_groundtruth(gt, t_ns)
    xe = x[inside]
    ate_m, out["alignment"] = ate_with_fallback(errs.t_ns, xe[:, 0:3], xe[:, 6:10], p, q,
                                                alignment)  # fmt: skip
    e, std = errs.e, np.sqrt(np.einsum("nii->ni", errs.P9))
    out.update(
        ate_rmse_m=ate_m,
        position_rmse_m=float(np.sqrt(np.mean(np.sum(e[:, 0:3] ** 2, axis=1)))),
        velocity_rmse_mps=float(np.sqrt(np.mean(np.sum(e[:, 3:6] ** 2, axis=1)))),
        attitude_rmse_deg=float(np.degrees(np.sqrt(np.mean(np.sum(e[:, 6:9] ** 2, axis=1))))),
        nees_mean=float(errs.nees.mean()),
        nees_dof=9,
        errors_alignment=errs.alignment,
        position_within_3sigma=float(np.mean(np.abs(e[:, 0:3]) <= 3.0 * std[:, 0:3])),
        evaluated_states=len(errs.t_ns),
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
