"""Trajectory accuracy through evo's Python API (so numbers equal ``evo_ape`` / ``evo_rpe``).

Absolute trajectory error (ATE) after ``se3`` / ``sim3`` (evo's Umeyama), ``posyaw`` (4-DoF, see
:mod:`svains.evaluation.alignment`) or no alignment; relative pose error (RPE) over travelled
distances. Poses are body-in-world: ``p_W_B`` (N, 3) m, ``q_W_B_wxyz`` (N, 4), ``t_ns`` (N,).
Estimate and reference are associated by nearest timestamp (evo's ``associate_trajectories``).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import AlignmentError, ConfigError
from svains.evaluation.alignment import align_posyaw
from svains.geometry.rotation import rotmat_to_quat

if TYPE_CHECKING:
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PoseTrajectory3D

# evo (with scipy.spatial, ~0.4 s) is imported by the functions that use it, so a command or a
# run that computes no metric never loads it.

F64 = NDArray[np.float64]
Alignment = Literal["se3", "posyaw", "none", "sim3"]
ALIGNMENTS: tuple[str, ...] = ("se3", "posyaw", "none", "sim3")


@dataclass
class AteResult:
    """ATE statistics (m) of the associated poses plus the aligned estimate (for plots).

    ``T_align`` (4, 4) maps estimate-world into reference-world (with ``scale`` for sim3);
    ``rot_rmse_deg`` is the RMSE of the attitude error angle after alignment.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int
    alignment: str
    scale: float
    rot_rmse_deg: float
    T_align: F64 = field(repr=False)
    t_ns: NDArray[np.int64] = field(repr=False)
    p_est_aligned: F64 = field(repr=False)
    q_est_aligned_wxyz: F64 = field(repr=False)
    p_ref: F64 = field(repr=False)
    errors_m: F64 = field(repr=False)

    def summary(self) -> dict[str, float | int | str]:
        """Scalars only (JSON friendly)."""
        d = asdict(self)
        return {k: v for k, v in d.items() if not isinstance(v, np.ndarray)}


@dataclass
class RpeResult:
    """Translation (m) and rotation (deg) RPE over pose pairs ``delta_m`` metres apart."""

    delta_m: float
    n_pairs: int
    trans_rmse: float
    trans_mean: float
    trans_median: float
    trans_max: float
    rot_rmse_deg: float
    rot_mean_deg: float


def to_evo(t_ns: ArrayLike, p: ArrayLike, q_wxyz: ArrayLike, name: str = "") -> PoseTrajectory3D:
    """evo trajectory (timestamps in seconds, as evo's TUM reader makes them)."""
    t = np.asarray(t_ns, dtype=np.int64)
    p = np.asarray(p, dtype=float).reshape(-1, 3)
    q = np.asarray(q_wxyz, dtype=float).reshape(-1, 4)
    if not (t.size == p.shape[0] == q.shape[0]):
        raise ConfigError(f"{name}: lengths differ: t {t.size}, p {p.shape[0]}, q {q.shape[0]}")
    if t.size == 0:
        raise ConfigError(f"{name}: empty trajectory")
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(
        positions_xyz=p, orientations_quat_wxyz=q, timestamps=t * 1e-9, name=name
    )


def associate(
    est: PoseTrajectory3D, ref: PoseTrajectory3D, max_diff_s: float
) -> tuple[PoseTrajectory3D, PoseTrajectory3D, NDArray[np.int64]]:
    """Matched copies (ref, est) and the indices of the kept estimate poses."""
    from evo.core import sync as evo_sync

    try:
        ref_m, est_m = evo_sync.associate_trajectories(ref, est, max_diff=max_diff_s)
    except evo_sync.SyncException as exc:
        raise ConfigError(f"no matching timestamps within {max_diff_s} s: {exc}") from exc
    idx = np.searchsorted(est.timestamps, est_m.timestamps)
    return ref_m, est_m, idx.astype(np.int64)


def rotation_angle_deg(R: F64) -> F64:
    """Angle (deg) of rotation matrices (N, 3, 3), via atan2(sin, cos) to stay exact near 0."""
    cos = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    axis = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    sin = 0.5 * np.linalg.norm(axis, axis=1)
    return np.degrees(np.arctan2(sin, cos))


def _stats(metric: evo_metrics.PE) -> dict[str, float]:
    return {k: float(v) for k, v in metric.get_all_statistics().items()}


# A rotation fitted to N positions is determined to about residual / (extent sqrt(N)) rad;
# above this the se3/sim3 fit turns the estimate by an arbitrary angle (a vehicle at rest: a
# 143° rotation error was printed for the EuRoC static start, whose own report said 0.62°).
MAX_ROTATION_UNCERTAINTY_RAD = 0.1


def _check_extent(p_aligned: F64, p_ref: F64, align: str) -> None:
    """AlignmentError when the reference positions (N, 3) barely move against the residual of
    the aligned estimate (N, 3) (see ``MAX_ROTATION_UNCERTAINTY_RAD``)."""
    a = p_ref - p_ref.mean(axis=0)
    extent = float(np.sqrt(np.linalg.eigvalsh(a.T @ a / len(a))[-1]))
    residual = float(np.sqrt(np.mean(np.sum((p_aligned - p_ref) ** 2, axis=1))))
    if residual > MAX_ROTATION_UNCERTAINTY_RAD * extent * np.sqrt(len(a)):
        raise AlignmentError(
            f"{align} alignment is undetermined: the reference moves {extent:.3g} m (RMS along "
            f"its main axis) against a {residual:.3g} m residual after the fit, so its rotation "
            "is arbitrary: use posyaw or none"
        )


def ate(
    t_est_ns: ArrayLike,
    p_est: ArrayLike,
    q_est_wxyz: ArrayLike,
    t_ref_ns: ArrayLike,
    p_ref: ArrayLike,
    q_ref_wxyz: ArrayLike,
    align: Alignment = "se3",
    max_diff_s: float = 0.01,
    up_W: ArrayLike = (0.0, 0.0, 1.0),
) -> AteResult:
    """Absolute trajectory error of an estimate against a reference (both body-in-world).

    ``align``: ``se3`` (evo Umeyama, rotation+translation), ``sim3`` (plus scale), ``posyaw``
    (yaw about ``up_W`` + translation) or ``none``. Poses are associated within ``max_diff_s``.
    """
    if align not in ALIGNMENTS:
        raise ConfigError(f"unknown alignment '{align}' (expected one of {', '.join(ALIGNMENTS)})")
    est = to_evo(t_est_ns, p_est, q_est_wxyz, "estimate")
    ref = to_evo(t_ref_ns, p_ref, q_ref_wxyz, "reference")
    ref_m, est_m, idx = associate(est, ref, max_diff_s)
    est_a = copy.deepcopy(est_m)
    T = np.eye(4)
    scale = 1.0
    if align in ("se3", "sim3"):
        if est_a.num_poses < 3:
            raise ConfigError(f"{align} alignment needs at least 3 matched poses")
        from evo.core.geometry import GeometryException

        try:
            R, t, s = est_a.align(ref_m, correct_scale=align == "sim3")
        except GeometryException as exc:
            raise AlignmentError(
                f"{align} alignment is undetermined ({exc}): the positions are (nearly) "
                "collinear or identical; use posyaw or none"
            ) from exc
        T[:3, :3], T[:3, 3], scale = R, t, float(s)
        _check_extent(est_a.positions_xyz, ref_m.positions_xyz, align)
    elif align == "posyaw":
        T = align_posyaw(est_a.positions_xyz, ref_m.positions_xyz, up_W)
        est_a.transform(T)
    from evo.core import metrics as evo_metrics

    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref_m, est_a))
    # Rotation error angle of inv(T_ref) T_est (what evo's APE rotation_angle_deg gives),
    # vectorised: evo's per-pose SO(3) log dominates the run time otherwise.
    R_ref = np.stack(ref_m.poses_se3)[:, :3, :3]
    R_est = np.stack(est_a.poses_se3)[:, :3, :3]
    rot_deg = rotation_angle_deg(np.einsum("nji,njk->nik", R_ref, R_est))
    s = _stats(ape)
    t_ns = np.asarray(t_est_ns, dtype=np.int64)[idx]
    return AteResult(
        rmse=s["rmse"], mean=s["mean"], median=s["median"], std=s["std"], min=s["min"],
        max=s["max"], n=int(est_a.num_poses), alignment=align, scale=scale,
        rot_rmse_deg=float(np.sqrt(np.mean(rot_deg**2))), T_align=T, t_ns=t_ns,
        p_est_aligned=np.array(est_a.positions_xyz), q_est_aligned_wxyz=rotmat_to_quat(R_est),
        p_ref=np.array(ref_m.positions_xyz),
        errors_m=np.array(ape.error),
    )  # fmt: skip


def rpe(
    t_est_ns: ArrayLike,
    p_est: ArrayLike,
    q_est_wxyz: ArrayLike,
    t_ref_ns: ArrayLike,
    p_ref: ArrayLike,
    q_ref_wxyz: ArrayLike,
    delta_m: list[float] | tuple[float, ...] = (1.0,),
    max_diff_s: float = 0.01,
    rel_delta_tol: float = 0.1,
) -> list[RpeResult]:
    """Relative pose error for each segment length in ``delta_m`` (metres travelled).

    As ``evo_rpe --delta D --delta_unit m``: consecutive pose pairs whose path length on the
    estimate is D within ``rel_delta_tol``. A length no pair reaches gives ``n_pairs = 0`` and NaN.
    """
    est = to_evo(t_est_ns, p_est, q_est_wxyz, "estimate")
    ref = to_evo(t_ref_ns, p_ref, q_ref_wxyz, "reference")
    ref_m, est_m, _ = associate(est, ref, max_diff_s)
    from evo.core import metrics as evo_metrics
    from evo.core.filters import FilterException

    out: list[RpeResult] = []
    for d in delta_m:
        if d <= 0:
            raise ConfigError(f"RPE segment length must be positive, got {d}")
        res = []
        for rel in (
            evo_metrics.PoseRelation.translation_part,
            evo_metrics.PoseRelation.rotation_angle_deg,
        ):
            m = evo_metrics.RPE(rel, delta=float(d), delta_unit=evo_metrics.Unit.meters,
                                rel_delta_tol=rel_delta_tol)  # fmt: skip
            try:
                m.process_data((ref_m, est_m))
            except FilterException:
                res.append(None)
                continue
            res.append((len(m.error), _stats(m)))
        if res[0] is None or res[1] is None:
            nan = float("nan")
            out.append(RpeResult(float(d), 0, nan, nan, nan, nan, nan, nan))
            continue
        (n, tr), (_, rot) = res
        out.append(
            RpeResult(
                float(d), n, tr["rmse"], tr["mean"], tr["median"], tr["max"], rot["rmse"],
                rot["mean"],
            )
        )  # fmt: skip
    return out
