"""Accuracy and consistency keys of ``report.json``: a run's estimates against ground truth.

The ATE is :func:`svains.evaluation.metrics.ate` (its figures equal ``evo_ape``'s). The
per-state errors (position, velocity, attitude RMSE, NEES) are taken after ``errors_alignment``:
``none`` when the run's world frame is the ground truth's (initialised from it, or GPS fixes it),
otherwise the alignment of the degrees of freedom the run cannot observe (``posyaw`` for an
inertial or visual-inertial filter: yaw about the up axis and translation, the usual VIO
convention). That yaw is fitted on positions and headings
(:func:`svains.evaluation.alignment.align_posyaw_poses`), so it stays determined when the vehicle
barely moves. The covariance is rotated with the states, so the NEES stays consistent.

The NEES is also reported per block (:func:`nees_blocks`): position, velocity, and the attitude
error about world axes split into tilt (roll/pitch, 2 dof) and yaw (1 dof). A reference frame
tilted from gravity can be levelled first (``R_W_Wref``, from
:mod:`svains.evaluation.reference_tilt`): the per-state errors and the NEES then compare with
the levelled reference; the ATE keeps the reference as it is (as ``evo_ape`` would).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.datasets.types import GroundTruth
from svains.errors import ConfigError, SvainsError
from svains.evaluation.alignment import align_posyaw_poses
from svains.evaluation.metrics import AteResult, ate
from svains.geometry.rotation import quat_multiply, quat_to_rotmat, rotmat_to_quat
from svains.replay.groundtruth import interpolate_groundtruth, navigation_errors, nees_of

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
log = logging.getLogger(__name__)

# Fallback order when an alignment is degenerate (a straight or too short trajectory leaves the
# rotation about its own line undetermined and the fit raises): drop to fewer degrees of freedom.
_FALLBACK: dict[str, tuple[str, ...]] = {
    "se3": ("se3", "posyaw", "none"),
    "sim3": ("sim3", "se3", "posyaw", "none"),
    "posyaw": ("posyaw", "none"),
    "none": ("none",),
}
# Alignments that keep metric scale, so states and covariances can be mapped with (R, t).
ERROR_ALIGNMENTS: tuple[str, ...] = ("none", "posyaw", "se3", "start", "start_position")


def ate_result_with_fallback(
    t_ns: I64,
    p_est: F64,
    q_est: F64,
    p_ref: F64,
    q_ref: F64,
    alignment: str = "se3",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> AteResult | None:
    """ATE of an estimate against a reference sampled at the same ``t_ns`` (N,), with
    ``alignment`` or, when that fit is degenerate (``AlignmentError`` on a straight trajectory,
    too few poses, a non-finite result), fewer degrees of freedom (``_FALLBACK``).
    ``None`` when even ``none`` fails; never raises for a degenerate geometry."""
    for align in _FALLBACK.get(alignment, (alignment, "none")):
        try:
            res = ate(t_ns, p_est, q_est, t_ns, p_ref, q_ref, align=align, up_W=up_W)  # type: ignore[arg-type]
        except (SvainsError, np.linalg.LinAlgError) as exc:
            # Expected on a short or straight run; the report's ``alignment`` names the fit
            # used, so this is no warning (it printed one per run and one per smoothed run).
            log.info("ATE with %s alignment undetermined (%s); trying fewer degrees of freedom",
                     align, exc)  # fmt: skip
            continue
        if np.isfinite(res.rmse):
            return res
    return None


def ate_with_fallback(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> tuple[float, str]:
    """ATE RMSE (m) and the alignment actually used (see :func:`ate_result_with_fallback`; a
    ``posyaw`` one turns about ``up_W``); the unaligned RMSE when every alignment fails."""
    res = ate_result_with_fallback(t_ns, p_est, q_est, p_ref, q_ref, alignment, up_W)
    if res is None:
        return float(np.sqrt(np.mean(np.sum((p_est - p_ref) ** 2, axis=1)))), "none"
    return res.rmse, res.alignment


def ate_rmse(
    t_ns: I64, p_est: F64, q_est: F64, p_ref: F64, q_ref: F64, alignment: str = "se3",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> float:
    """Absolute trajectory error RMSE (m) after ``alignment`` (with ``ate_with_fallback``'s
    fallback when it is degenerate; ``posyaw`` about ``up_W``), reference sampled at ``t_ns``;
    equals ``evo_ape``'s."""
    return ate_with_fallback(t_ns, p_est, q_est, p_ref, q_ref, alignment, up_W)[0]


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


def aligned_for_errors(
    t_in: I64, xe: F64, P: F64, p: F64, q: F64, errors_alignment: str, up_W: ArrayLike
) -> tuple[F64, F64, str]:
    """States (N, nx) and covariances (N, 9, 9) after ``errors_alignment`` against the reference
    ``p``, ``q`` at ``t_in``, and the alignment used (``se3`` falls back when degenerate)."""
    if errors_alignment in ("posyaw", "start"):
        # Positions and headings: a resting vehicle's positions leave the yaw undetermined.
        # "start": the first state alone, the frame a start at the local origin defines.
        n = 1 if errors_alignment == "start" else len(xe)
        T = align_posyaw_poses(xe[:n, 0:3], quat_to_rotmat(xe[:n, 6:10]), p[:n],
                               quat_to_rotmat(q[:n]), up_W)  # fmt: skip
        xe, P = align_states(xe, P, T)
    elif errors_alignment == "start_position":
        # The first state's position alone: a local frame whose heading a magnetometer made
        # absolute (a yaw fitted over the run turned that heading, and its misfit shifted a
        # resting start's positions: NEES 950 where σ_p was 0.1 m, a probe).
        T_Wref_West = np.eye(4)
        T_Wref_West[:3, 3] = p[0] - xe[0, 0:3]
        xe, P = align_states(xe, P, T_Wref_West)
    elif errors_alignment == "se3":
        fit = ate_result_with_fallback(t_in, xe[:, 0:3], xe[:, 6:10], p, q, "se3", up_W)
        if fit is None:
            return xe, P, "none"
        xe, P = align_states(xe, P, fit.T_align)
        return xe, P, fit.alignment
    return xe, P, errors_alignment


# Degrees of freedom of each NEES block (``report.json``'s ``nees_blocks_dof``).
NEES_BLOCKS_DOF: dict[str, int] = {"position": 3, "velocity": 3, "roll_pitch": 2, "yaw": 1}


def vertical_basis(up_W: ArrayLike) -> F64:
    """Rows (3, 3): two horizontal unit vectors and the unit ``up_W``, right-handed; the
    identity for ``up_W`` = +z."""
    u = np.asarray(up_W, float) / np.linalg.norm(up_W)
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = a - (a @ u) * u
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1), u])


def nees_blocks(e: F64, P9: F64, R_W_B: F64, up_W: ArrayLike = (0.0, 0.0, 1.0)) -> dict[str, F64]:
    """NEES (N,) of each block of errors ``e`` (N, 9) (p, v, δθ_B) with covariances ``P9``
    (N, 9, 9), each against its own marginal covariance (``NEES_BLOCKS_DOF``).

    The attitude error is on the right, body axes (``R = R̂ Exp(δθ_B)``), hence about world
    axes ``δθ_W = R̂_W_B δθ_B`` (``R = Exp(δθ_W) R̂``), covariance ``R̂ P_θθ R̂ᵀ``. In the
    basis of :func:`vertical_basis` (world x, y, z when ``up_W`` is z), its two horizontal
    components are the tilt (``roll_pitch``) and its vertical one the ``yaw`` error.
    ``R_W_B`` (N, 3, 3) is the estimate's attitude.
    """
    V = vertical_basis(up_W)
    J = np.einsum("ij,njk->nik", V, R_W_B)  # δθ_V = V R̂ δθ_B
    e_V = np.einsum("nij,nj->ni", J, e[:, 6:9])
    P_V = J @ P9[:, 6:9, 6:9] @ J.transpose(0, 2, 1)
    return {
        "position": nees_of(e[:, 0:3], P9[:, 0:3, 0:3]),
        "velocity": nees_of(e[:, 3:6], P9[:, 3:6, 3:6]),
        "roll_pitch": nees_of(e_V[:, 0:2], P_V[:, 0:2, 0:2]),
        "yaw": e_V[:, 2] ** 2 / P_V[:, 2, 2],
    }


def reference_at(
    gt: GroundTruth, t_ns: I64, R_W_Wref: ArrayLike | None = None
) -> tuple[NDArray[np.bool_], F64, F64, F64]:
    """Ground truth at ``t_ns`` (:func:`interpolate_groundtruth`: mask, p, v, q), rotated by
    ``R_W_Wref`` (3, 3) from the reference's world into the levelled one when given."""
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    return (inside, *levelled(p, v, q, R_W_Wref))


def levelled(p: F64, v: F64, q_wxyz: F64, R_W_Wref: ArrayLike | None) -> tuple[F64, F64, F64]:
    """Reference positions, velocities (N, 3) and attitudes (N, 4) rotated by ``R_W_Wref``
    (3, 3) into the levelled world (unchanged when None)."""
    if R_W_Wref is None:
        return p, v, q_wxyz
    R = np.asarray(R_W_Wref, float)
    return p @ R.T, v @ R.T, quat_multiply(rotmat_to_quat(R)[None, :], q_wxyz)


@dataclass(frozen=True)
class StateErrors:
    """Per-state errors against ground truth after an alignment: ``t_ns`` (N,) logged times
    inside the ground truth's span, ``e`` (N, 9) ``truth ⊟ estimate`` of (p m, v m/s, δθ rad),
    ``P9`` (N, 9, 9) covariances mapped by the same alignment, ``alignment`` the one used,
    ``x`` (N, nx) the aligned states."""

    t_ns: I64
    e: F64
    P9: F64
    alignment: str
    x: F64
    up_W: F64 = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    @property
    def nees(self) -> F64:
        """NEES (N,) of (p, v, δθ), 9 dof."""
        return nees_of(self.e, self.P9)

    @property
    def nees_blocks(self) -> dict[str, F64]:
        """NEES (N,) per block (:func:`nees_blocks`; dof in ``NEES_BLOCKS_DOF``)."""
        return nees_blocks(self.e, self.P9, quat_to_rotmat(self.x[:, 6:10]), self.up_W)


def state_errors(
    t_ns: I64,
    x: F64,
    P9: F64,
    gt: GroundTruth | None,
    errors_alignment: str = "none",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
    R_W_Wref: ArrayLike | None = None,
) -> StateErrors | None:
    """Errors of states ``x`` (T, nx) with covariances ``P9`` (T, 9, 9) at ``t_ns`` (T,) after
    ``errors_alignment`` (``none``, ``posyaw`` about ``up_W``, ``se3``, ``start``: the first
    state's yaw and position, ``start_position``: its position) against the ground
    truth levelled by ``R_W_Wref`` (3, 3) when given; ``None`` without ground truth or with
    fewer than 2 states inside its span."""
    if errors_alignment not in ERROR_ALIGNMENTS:
        raise ConfigError(
            f"unknown errors alignment {errors_alignment!r} (one of {', '.join(ERROR_ALIGNMENTS)})"
        )
    if gt is None or len(gt.t_ns) < 2:
        return None
    inside, p, v, q = reference_at(gt, t_ns, R_W_Wref)
    if inside.sum() < 2:
        return None
    t_in = np.asarray(t_ns)[inside]
    xe, P, used = aligned_for_errors(t_in, x[inside], P9[inside], p, q, errors_alignment, up_W)
    up = np.asarray(up_W, float) / np.linalg.norm(up_W)
    return StateErrors(t_in, navigation_errors(xe, p, v, q), P, used, xe, up)


def accuracy_report(
    t_ns: I64,
    x: F64,
    P9: F64,
    gt: GroundTruth | None,
    alignment: str = "se3",
    errors_alignment: str = "none",
    up_W: ArrayLike = (0.0, 0.0, 1.0),
    R_W_Wref: ArrayLike | None = None,
) -> dict[str, Any]:
    """Report keys against ground truth (None values when there is none).

    ``ate_rmse_m`` after ``alignment`` (key ``alignment``: the one used after fallback);
    position/velocity/attitude RMSE, NEES (whole, ``nees_mean``, and per block,
    ``nees_blocks`` with ``nees_blocks_dof``), drift and the 3σ coverage after
    ``errors_alignment`` (``none``, ``posyaw`` about ``up_W`` or ``se3``; key
    ``errors_alignment``: the one used) against the reference levelled by ``R_W_Wref`` (3, 3)
    when given, from :func:`state_errors`. The ATE uses the reference as it is.
    """
    keys = ("ate_rmse_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean",
            "nees_blocks")  # fmt: skip
    out: dict[str, Any] = dict.fromkeys(keys)
    out["alignment"] = alignment
    out["errors_alignment"] = errors_alignment
    errs = state_errors(t_ns, x, P9, gt, errors_alignment, up_W, R_W_Wref)
    if errs is None:
        return out
    assert gt is not None  # state_errors returns None without ground truth
    inside, p, v, q = interpolate_groundtruth(gt, t_ns)
    xe = x[inside]
    fit = ate_result_with_fallback(errs.t_ns, xe[:, 0:3], xe[:, 6:10], p, q, alignment, up_W)
    if fit is None:  # every fit degenerate: the unaligned RMSE
        ate_m, out["alignment"] = ate_with_fallback(errs.t_ns, xe[:, 0:3], xe[:, 6:10], p, q,
                                                    alignment, up_W)  # fmt: skip
    else:
        ate_m, out["alignment"] = fit.rmse, fit.alignment
        # how far the fit turned the estimate's vertical (a z-up world): a gravity-aligned run
        # tilted 7° by an se3 fit over KITTI raw read 0.30 m, `evaluate --align posyaw` 0.81 m
        out["ate_fit_tilt_deg"] = fit.tilt_about_deg(up_W)
    e, std = errs.e, np.sqrt(np.einsum("nii->ni", errs.P9))
    xa = errs.x
    p, _, q = levelled(p, v, q, R_W_Wref)  # the ATE above keeps the reference as it is
    out.update(drift_report(xa[:, 0:3], quat_to_rotmat(xa[:, 6:10]), p, quat_to_rotmat(q)))
    out.update(
        ate_rmse_m=ate_m,
        position_rmse_m=float(np.sqrt(np.mean(np.sum(e[:, 0:3] ** 2, axis=1)))),
        velocity_rmse_mps=float(np.sqrt(np.mean(np.sum(e[:, 3:6] ** 2, axis=1)))),
        attitude_rmse_deg=float(np.degrees(np.sqrt(np.mean(np.sum(e[:, 6:9] ** 2, axis=1))))),
        nees_mean=float(errs.nees.mean()),
        nees_dof=9,
        nees_blocks={k: float(v.mean()) for k, v in errs.nees_blocks.items()},
        nees_blocks_dof=dict(NEES_BLOCKS_DOF),
        errors_alignment=errs.alignment,
        position_within_3sigma=float(np.mean(np.abs(e[:, 0:3]) <= 3.0 * std[:, 0:3])),
        evaluated_states=len(errs.t_ns),
    )
    if errs.alignment == "posyaw":
        # The fit over the whole run takes part of an excursion's error out of every other
        # stretch, where the covariance is small: a consistent run with one excursion read
        # as 30x overconfident and more (a user's probe). The frame the start defines does not.
        anchored = state_errors(t_ns, x, P9, gt, "start", up_W, R_W_Wref)
        if anchored is not None:
            out["nees_start_anchored"] = float(anchored.nees.mean())
            out["nees_blocks_start_anchored"] = {k: float(v.mean())
                                                 for k, v in anchored.nees_blocks.items()}
    return out


# Segment lengths (m) of the KITTI-style drift figures in ``report.json`` (``drift_50m_pct``, ...).
DRIFT_SEGMENTS_M: tuple[float, ...] = (50.0, 100.0)


def path_distances(p_W: F64) -> F64:
    """Cumulative path length (N,) m along positions (N, 3), 0 at the first."""
    steps = np.linalg.norm(np.diff(np.asarray(p_W, float), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def segment_drift_pct(
    p_est: F64, R_est: F64, p_ref: F64, R_ref: F64, length_m: float
) -> float | None:
    """KITTI odometry's translational error over ``length_m`` segments, % of the length.

    For every start sample i, the segment ends at the first sample j whose reference path
    length from i is at least ``length_m``. The relative-pose error
    ``E = (T_est_i^-1 T_est_j)^-1 (T_ref_i^-1 T_ref_j)`` has translation ``t_E``; the figure is
    the mean of ``|t_E| / length_m`` over all segments, times 100. (The KITTI devkit steps the
    start by 10 frames; every sample is used here.) Poses: body positions (N, 3) m and
    attitudes ``R_W_B`` (N, 3, 3), both sampled at the same times. None when the reference path
    is shorter than ``length_m``. Invariant to a rigid transform of either trajectory.
    """
    dist = path_distances(p_ref)
    i = np.arange(len(dist))
    j = np.searchsorted(dist, dist + length_m, side="left")
    ok = j < len(dist)
    if not ok.any():
        return None
    i, j = i[ok], j[ok]

    def relative(p: F64, R: F64) -> tuple[F64, F64]:
        Ri = R[i]
        return Ri.transpose(0, 2, 1) @ R[j], np.einsum("nji,nj->ni", Ri, p[j] - p[i])

    dR_e, dp_e = relative(p_est, R_est)
    _, dp_r = relative(p_ref, R_ref)
    # E = (dR_e, dp_e)^-1 (dR_r, dp_r): translation dR_e^T (dp_r - dp_e).
    t_err = np.einsum("nji,nj->ni", dR_e, dp_r - dp_e)
    return float(np.mean(np.linalg.norm(t_err, axis=1)) / length_m * 100.0)


def drift_report(p_est: F64, R_est: F64, p_ref: F64, R_ref: F64) -> dict[str, Any]:
    """``path_length_m``, ``final_error_m`` and ``final_error_pct`` (final position error over
    the reference path length, %), and ``drift_<L>m_pct`` (:func:`segment_drift_pct`) for each
    ``DRIFT_SEGMENTS_M`` length (None when the path is shorter). Inputs as
    :func:`segment_drift_pct`, already in the reference's world frame."""
    path = float(path_distances(p_ref)[-1])
    final = float(np.linalg.norm(p_est[-1] - p_ref[-1]))
    out: dict[str, Any] = {
        "path_length_m": path,
        "final_error_m": final,
        "final_error_pct": 100.0 * final / path if path > 0 else None,
    }
    for length in DRIFT_SEGMENTS_M:
        out[f"drift_{length:g}m_pct"] = segment_drift_pct(p_est, R_est, p_ref, R_ref, length)
    return out


def gps_outage_report(
    t_ns: I64, x: F64, std: F64, gps_t_ns: I64, gt: GroundTruth, min_gap_s: float = 3.0
) -> dict[str, Any]:
    """Position error while GPS is available, and its growth over each GPS outage.

    An outage is a gap longer than ``min_gap_s`` between consecutive GPS fixes, from the start
    of the run to the first fix (``"from_start": true``) or from the last fix to the end of the
    run (``--gps-until``; ``"to_end": true``); without any fix the whole run is one. Returns
    ``position_rmse_with_gps_m`` (logged states outside outages) and ``gps_outages``: for each,
    start/end (s from the first state), position error at the start and at the end, its maximum,
    and the filter's 3σ position bound (norm of the 3σ per axis) at the end.
    """
    inside, p, _, _ = interpolate_groundtruth(gt, t_ns)
    t = np.asarray(t_ns)[inside]
    err = np.linalg.norm(p - x[inside, 0:3], axis=1)
    sig3 = 3.0 * np.linalg.norm(std[inside, 0:3], axis=1)
    g = np.asarray(gps_t_ns, dtype=np.int64)
    gap_ns = int(min_gap_s * 1e9)
    gaps = np.flatnonzero(np.diff(g) > gap_ns)
    windows = [(int(g[k]), int(g[k + 1]), {}) for k in gaps]
    if len(t) and not g.size:
        # Not one fix fused (e.g. ``--gps-outage`` over the whole run): all of it is outage.
        windows.append((int(t[0]), int(t[-1]) + 1, {"from_start": True, "to_end": True}))
    elif len(t):
        if int(g[0]) - int(t[0]) > gap_ns:
            windows.insert(0, (int(t[0]), int(g[0]), {"from_start": True}))
        if int(t[-1]) - int(g[-1]) > gap_ns:
            windows.append((int(g[-1]), int(t[-1]) + 1, {"to_end": True}))
    in_outage = np.zeros(len(t), dtype=bool)
    outages = []
    for a, b, marks in windows:
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
                **marks,
            }
        )
    ok = ~in_outage
    return {
        "position_rmse_with_gps_m": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else None,
        "gps_outages": outages,
    }
