"""Trajectory accuracy in numpy; the figures equal evo's ``evo_ape`` / ``evo_rpe`` ones.

Absolute trajectory error (ATE) after ``se3`` / ``sim3`` (Umeyama's least-squares fit),
``posyaw`` (4-DoF, see :mod:`svains.evaluation.alignment`) or no alignment; relative pose error
(RPE) over travelled distances. Poses are body-in-world: ``p_W_B`` (N, 3) m, ``q_W_B_wxyz``
(N, 4), ``t_ns`` (N,). Estimate and reference are associated by nearest timestamp, with the
semantics of evo's ``associate_trajectories``.

evo (GPL-3) is not a dependency of the library: it is the oracle of
``tests/test_metrics_vs_evo.py``, which checks every figure here against it to 1e-9.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import AlignmentError, ConfigError
from svains.evaluation.alignment import align_posyaw
from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Alignment = Literal["se3", "posyaw", "none", "sim3"]
ALIGNMENTS: tuple[str, ...] = ("se3", "posyaw", "none", "sim3")
log = logging.getLogger(__name__)


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

    @property
    def fit_tilt_deg(self) -> float:
        """Angle (deg) by which the alignment turns the estimate's z axis (the tilt of a z-up
        world): 0 for posyaw and none. A large one after se3/sim3 means the fit traded the
        estimate's tilt for position error (drift along a long path), and the rotation errors
        after it are the fit's, not the estimate's."""
        return self.tilt_about_deg((0.0, 0.0, 1.0))

    def tilt_about_deg(self, up: ArrayLike) -> float:
        """Angle (deg) by which the alignment turns the world's ``up`` (3,) (``fit_tilt_deg``
        for a world that is not z-up: KITTI odometry's camera world has y down)."""
        u = np.asarray(up, dtype=float) / np.linalg.norm(up)
        Ru = np.asarray(self.T_align, dtype=float)[:3, :3] @ u
        return float(np.degrees(np.arccos(np.clip(Ru @ u / np.linalg.norm(Ru), -1.0, 1.0))))

    def summary(self) -> dict[str, float | int | str]:
        """Scalars only (JSON friendly)."""
        d = asdict(self)
        out = {k: v for k, v in d.items() if not isinstance(v, np.ndarray)}
        out["fit_tilt_deg"] = self.fit_tilt_deg
        return out


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


@dataclass(frozen=True)
class PoseTrajectory:
    """Timestamped body-in-world poses: ``t_ns`` (N,), ``p_W_B`` (N, 3) m, ``q_W_B_wxyz`` (N, 4)
    as given (not normalised). The read-only ``timestamps`` (s), ``positions_xyz``,
    ``orientations_quat_wxyz`` and ``num_poses`` mirror evo's ``PoseTrajectory3D`` for callers
    of the former evo-based API."""

    t_ns: I64
    p_W_B: F64
    q_W_B_wxyz: F64
    name: str = ""

    @property
    def t_s(self) -> F64:
        """Timestamps (N,) in seconds, as float64 (evo's file readers give seconds)."""
        return self.t_ns * 1e-9

    @property
    def timestamps(self) -> F64:
        """Alias of ``t_s`` (evo's name)."""
        return self.t_s

    @property
    def positions_xyz(self) -> F64:
        """Alias of ``p_W_B`` (evo's name)."""
        return self.p_W_B

    @property
    def orientations_quat_wxyz(self) -> F64:
        """Alias of ``q_W_B_wxyz`` (evo's name)."""
        return self.q_W_B_wxyz

    @property
    def num_poses(self) -> int:
        """N."""
        return int(self.t_ns.size)

    @property
    def R_W_B(self) -> F64:
        """Rotation matrices (N, 3, 3) of the normalised quaternions (see :func:`rotmats`)."""
        return rotmats(self.q_W_B_wxyz)

    def take(self, idx: ArrayLike) -> PoseTrajectory:
        """The poses at indices ``idx`` (M,) (repeats allowed), in that order."""
        i = np.asarray(idx, dtype=np.int64)
        return PoseTrajectory(self.t_ns[i], self.p_W_B[i], self.q_W_B_wxyz[i], self.name)


def to_trajectory(
    t_ns: ArrayLike, p: ArrayLike, q_wxyz: ArrayLike, name: str = ""
) -> PoseTrajectory:
    """Checked trajectory of ``t_ns`` (N,), positions (N, 3) m and quaternions (N, 4) wxyz."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    p = np.array(p, dtype=float).reshape(-1, 3)
    q = np.array(q_wxyz, dtype=float).reshape(-1, 4)
    if not (t.size == p.shape[0] == q.shape[0]):
        raise ConfigError(f"{name}: lengths differ: t {t.size}, p {p.shape[0]}, q {q.shape[0]}")
    if t.size == 0:
        raise ConfigError(f"{name}: empty trajectory")
    return PoseTrajectory(t, p, q, name)


# Former name, from when the trajectory was an evo ``PoseTrajectory3D``; same arguments, and the
# result keeps evo's attribute names.
to_evo = to_trajectory

# Below this squared norm a quaternion is taken as the identity rotation, as evo does (its
# transformations module: 4 machine epsilons), so a degenerate input gives the same figures.
_QUAT_NORM2_IDENTITY = 4.0 * float(np.finfo(float).eps)


def rotmats(q_wxyz: ArrayLike) -> F64:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) wxyz, normalised first (trajectory files
    round them); a near-zero quaternion gives the identity."""
    q = np.asarray(q_wxyz, dtype=float).reshape(-1, 4)
    n2 = np.sum(q * q, axis=1)
    tiny = n2 < _QUAT_NORM2_IDENTITY
    norm = np.sqrt(np.where(tiny, 1.0, n2))[:, None]
    unit = np.where(tiny[:, None], [1.0, 0.0, 0.0, 0.0], q / norm)
    return quat_to_rotmat(unit)


def matching_time_indices(t_1_s: ArrayLike, t_2_s: ArrayLike, max_diff_s: float) -> tuple[I64, I64]:
    """Indices (M,), (M,) pairing each time of ``t_1_s`` (N1,) s with its nearest in ``t_2_s``
    (N2,) s, kept when at most ``max_diff_s`` apart (ties: the earlier one of ``t_2_s``).

    Same pairs as evo's ``matching_time_indices``: with ``t_2_s`` sorted, times of ``t_1_s``
    outside its span by more than ``max_diff_s`` are dropped and the nearest neighbour is one of
    the two around the insertion point; unsorted, a full nearest search. Several times of
    ``t_1_s`` may share one of ``t_2_s``. Differences are taken in seconds (float64), as evo does.
    """
    t1 = np.asarray(t_1_s, dtype=float).reshape(-1)
    t2 = np.asarray(t_2_s, dtype=float).reshape(-1)
    md = float(max_diff_s)
    if not np.all(np.diff(t2) >= 0.0):
        log.warning("timestamps are not sorted: nearest-time association by full search")
        best = np.empty(t1.size, dtype=np.int64)
        ok = np.zeros(t1.size, dtype=bool)
        chunk = max(1, 2_000_000 // max(t2.size, 1))  # bounds the (chunk, N2) difference table
        for a in range(0, t1.size, chunk):
            d = np.abs(t2[None, :] - t1[a : a + chunk, None])
            j = np.argmin(d, axis=1)
            best[a : a + chunk] = j
            ok[a : a + chunk] = d[np.arange(j.size), j] <= md
        return np.flatnonzero(ok).astype(np.int64), best[ok]
    inside = (t1 >= t2[0] - md) & (t1 <= t2[-1] + md)
    upper = np.minimum(np.searchsorted(t2, t1, side="right"), t2.size - 1)
    lower = np.maximum(upper - 1, 0)
    d_up = t2[upper] - t1
    d_low = np.where(upper > 0, t1 - t2[lower], np.inf)
    take_up = (d_up <= md) & (d_up < d_low)
    take_low = ~take_up & (d_low <= md) & (d_low <= d_up)
    keep = inside & (take_up | take_low)
    j = np.where(take_up, upper, lower)
    return np.flatnonzero(keep).astype(np.int64), j[keep].astype(np.int64)


# A nearest-time difference this close to ``max_diff_s`` (ns) is decided by rounding: float
# seconds (evo's) and nanoseconds (ours) may pair it differently.
AMBIGUOUS_NS = 1000
# ...warned when at least this share of the poses has one.
AMBIGUOUS_SHARE = 0.05


def _warn_ambiguous_pairs(t_short_ns: NDArray[np.int64], t_long_ns: NDArray[np.int64],
                          max_diff_s: float) -> None:  # fmt: skip
    """Warn when many poses' nearest-time differences sit at ``max_diff_s`` to within
    ``AMBIGUOUS_NS`` (a 10 Hz estimate 10 ms off a 20 Hz reference, ``--max-diff 0.01``: evo
    kept 1157 of its 1448 poses, the same in exact nanoseconds 578, a user's probe)."""
    if t_long_ns.size == 0 or t_short_ns.size == 0 or np.any(np.diff(t_long_ns) < 0):
        return
    k = np.searchsorted(t_long_ns, t_short_ns)
    up, low = np.minimum(k, t_long_ns.size - 1), np.maximum(k - 1, 0)
    d = np.minimum(np.abs(t_long_ns[up] - t_short_ns), np.abs(t_short_ns - t_long_ns[low]))
    # exact stamps (d = 0) are never ambiguous, whatever --max-diff (1 us: a review)
    n = int(np.sum((np.abs(d - round(max_diff_s * 1e9)) <= AMBIGUOUS_NS) & (d > 0)))
    if n >= max(2, AMBIGUOUS_SHARE * t_short_ns.size):
        log.warning("%d of %d poses are %g s from their nearest in time to within 1 us: "
                    "whether each is paired is decided by rounding (float seconds and "
                    "nanoseconds may differ, so may tools); give a --max-diff away from it "
                    "(e.g. %g s)", n, t_short_ns.size, max_diff_s,
                    1.5 * max_diff_s)  # fmt: skip


def associate(
    est: PoseTrajectory, ref: PoseTrajectory, max_diff_s: float, warn_ambiguous: bool = True
) -> tuple[PoseTrajectory, PoseTrajectory, NDArray[np.int64]]:
    """Matched copies (ref, est) and the indices (M,) of the kept estimate poses.

    As evo's ``associate_trajectories(ref, est)``: every pose of the trajectory with fewer poses
    (the estimate on a tie) is paired with the nearest pose in time of the other
    (:func:`matching_time_indices`), unpaired ones are dropped. ``warn_ambiguous``: warn when
    many poses' nearest differences sit at ``max_diff_s`` (``_warn_ambiguous_pairs``).
    """
    est_is_longer = est.num_poses > ref.num_poses
    short, long_ = (ref, est) if est_is_longer else (est, ref)
    i_short, i_long = matching_time_indices(short.t_s, long_.t_s, max_diff_s)
    if warn_ambiguous:
        _warn_ambiguous_pairs(short.t_ns, long_.t_ns, max_diff_s)
    if i_short.size == 0:
        raise ConfigError(
            f"no matching timestamps within {max_diff_s} s: estimate spans "
            f"[{est.t_s.min():.9f}, {est.t_s.max():.9f}] s ({est.num_poses} poses), reference "
            f"[{ref.t_s.min():.9f}, {ref.t_s.max():.9f}] s ({ref.num_poses} poses)"
        )
    i_ref, i_est = (i_short, i_long) if est_is_longer else (i_long, i_short)
    return ref.take(i_ref), est.take(i_est), i_est


def rotation_angle_deg(R: F64) -> F64:
    """Angle (deg) of rotation matrices (N, 3, 3), via atan2(sin, cos) to stay exact near 0."""
    cos = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    axis = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    sin = 0.5 * np.linalg.norm(axis, axis=1)
    return np.degrees(np.arctan2(sin, cos))


def error_statistics(errors: ArrayLike) -> dict[str, float]:
    """rmse, mean, median, std (population, ddof 0), min, max and sse (sum of squares) of
    errors (N,), N >= 1: evo's ``get_all_statistics`` figures."""
    e = np.asarray(errors, dtype=float).reshape(-1)
    sq = e * e
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
    }


def umeyama_alignment(
    p_src: ArrayLike, p_dst: ArrayLike, with_scale: bool = False
) -> tuple[F64, F64, float]:
    """Least-squares ``R`` (3, 3), ``t`` (3,), ``s`` with ``p_dst ≈ s R p_src + t`` for points
    (N, 3) (Umeyama 1991; ``s`` = 1 without scale). ``R`` is a proper rotation: when the SVD of
    the cross-covariance gives a reflection, the last singular direction is flipped.

    AlignmentError when fewer than 2 singular values of the cross-covariance exceed machine
    epsilon (the rule evo applies, so the same inputs are refused): identical or collinear points.
    """
    x = np.asarray(p_src, dtype=float)
    y = np.asarray(p_dst, dtype=float)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ConfigError(f"Umeyama alignment needs two (N, 3) arrays, got {x.shape}, {y.shape}")
    n = x.shape[0]
    xc = x - x.mean(axis=0)
    yc = y - y.mean(axis=0)
    # Summed pose by pose (a reduction over the first axis is sequential), the order evo uses,
    # so a rank decision on the edge of the threshold comes out the same.
    cov = (yc[:, :, None] * xc[:, None, :]).sum(axis=0) * (1.0 / n)
    U, d, Vt = np.linalg.svd(cov)
    rank = int(np.count_nonzero(d > np.finfo(float).eps))
    if rank < 2:
        raise AlignmentError(f"degenerate point sets: cross-covariance rank {rank} < 2")
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2] = -1.0  # reflection: take the best proper rotation instead
    R = (U * S) @ Vt
    s = float(np.sum(d * S) / (np.sum(xc * xc) / n)) if with_scale else 1.0
    t = y.mean(axis=0) - s * (R @ x.mean(axis=0))
    return R, t, s


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

    ``align``: ``se3`` (Umeyama, rotation+translation), ``sim3`` (plus scale), ``posyaw``
    (yaw about ``up_W`` + translation) or ``none``. Poses are associated within ``max_diff_s``.
    The statistics are those of ``evo_ape`` (translation part) on the same poses.
    """
    if align not in ALIGNMENTS:
        raise ConfigError(f"unknown alignment '{align}' (expected one of {', '.join(ALIGNMENTS)})")
    est = to_trajectory(t_est_ns, p_est, q_est_wxyz, "estimate")
    ref = to_trajectory(t_ref_ns, p_ref, q_ref_wxyz, "reference")
    ref_m, est_m, idx = associate(est, ref, max_diff_s)
    p_e = est_m.p_W_B
    R_e = est_m.R_W_B
    T = np.eye(4)
    scale = 1.0
    if align in ("se3", "sim3"):
        if est_m.num_poses < 3:
            raise ConfigError(f"{align} alignment needs at least 3 matched poses")
        try:
            R, t, scale = umeyama_alignment(p_e, ref_m.p_W_B, with_scale=align == "sim3")
        except AlignmentError as exc:
            raise AlignmentError(
                f"{align} alignment is undetermined ({exc}): the positions are (nearly) "
                "collinear or identical; use posyaw or none"
            ) from exc
        T[:3, :3], T[:3, 3] = R, t
        p_e = (scale * p_e) @ R.T + t  # scaled first, then moved, as evo's sim3 alignment
        R_e = R @ R_e
        _check_extent(p_e, ref_m.p_W_B, align)
    elif align == "posyaw":
        T = align_posyaw(p_e, ref_m.p_W_B, up_W)
        p_e = p_e @ T[:3, :3].T + T[:3, 3]
        R_e = T[:3, :3] @ R_e
    errors = np.linalg.norm(p_e - ref_m.p_W_B, axis=1)
    # Attitude error angle of R_ref⁻¹ R_est (evo's APE w.r.t. the rotation angle).
    rot_deg = rotation_angle_deg(np.einsum("nji,njk->nik", ref_m.R_W_B, R_e))
    s = error_statistics(errors)
    return AteResult(
        rmse=s["rmse"], mean=s["mean"], median=s["median"], std=s["std"], min=s["min"],
        max=s["max"], n=est_m.num_poses, alignment=align, scale=scale,
        rot_rmse_deg=float(np.sqrt(np.mean(rot_deg**2))), T_align=T, t_ns=est.t_ns[idx],
        p_est_aligned=p_e, q_est_aligned_wxyz=rotmat_to_quat(R_e), p_ref=ref_m.p_W_B.copy(),
        errors_m=errors,
    )  # fmt: skip


def path_pairs(p_W: F64, delta_m: float) -> tuple[I64, I64]:
    """Consecutive pose pairs (i, j), (M,) each, at least ``delta_m`` m of path apart along
    positions (N, 3): walking the path from pose 0, the first pose whose path length since the
    last kept pose reaches ``delta_m`` is kept (the overshoot is not carried over); each kept pose
    pairs with the next one. The pairs of evo's RPE in metres with consecutive pairs."""
    steps = np.linalg.norm(np.diff(np.asarray(p_W, dtype=float), axis=0), axis=1)
    kept = [0]
    walked = 0.0
    # A running sum, restarted at each kept pose: a cumulative sum would round differently and
    # could move a pair by one pose where the path length is within rounding of delta_m.
    for i, step in enumerate(steps.tolist(), start=1):
        walked += step
        if walked >= delta_m:
            kept.append(i)
            walked = 0.0
    k = np.asarray(kept, dtype=np.int64)
    return k[:-1], k[1:]


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
    warn_ambiguous: bool = True,
) -> list[RpeResult]:
    """Relative pose error for each segment length in ``delta_m`` (metres travelled).

    As ``evo_rpe --delta D --delta_unit m`` (consecutive pairs): pose pairs of
    :func:`path_pairs` on the associated estimate, error ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` of
    reference poses Q and estimated poses P; translation ``|t_E|`` m, rotation angle of ``R_E``
    deg. A length no pair reaches gives ``n_pairs = 0`` and NaN. ``rel_delta_tol`` is accepted
    for compatibility: like evo's, the consecutive-pair selection does not use it.
    ``warn_ambiguous``: warn of pairings decided by rounding (``associate``; off where the ATE
    of the same trajectories said it already).
    """
    del rel_delta_tol  # only evo's all-pairs mode uses a tolerance
    est = to_trajectory(t_est_ns, p_est, q_est_wxyz, "estimate")
    ref = to_trajectory(t_ref_ns, p_ref, q_ref_wxyz, "reference")
    ref_m, est_m, _ = associate(est, ref, max_diff_s, warn_ambiguous)
    R_q, R_p = ref_m.R_W_B, est_m.R_W_B
    out: list[RpeResult] = []
    for d in delta_m:
        if d <= 0:
            raise ConfigError(f"RPE segment length must be positive, got {d}")
        i, j = path_pairs(est_m.p_W_B, float(d))
        if i.size == 0:
            nan = float("nan")
            out.append(RpeResult(float(d), 0, nan, nan, nan, nan, nan, nan))
            continue
        # Relative motions in the body frame at i: rotation R_i⁻¹ R_j, translation R_i⁻¹ Δp.
        dR_q = np.einsum("nji,njk->nik", R_q[i], R_q[j])
        dR_p = np.einsum("nji,njk->nik", R_p[i], R_p[j])
        dt_q = np.einsum("nji,nj->ni", R_q[i], ref_m.p_W_B[j] - ref_m.p_W_B[i])
        dt_p = np.einsum("nji,nj->ni", R_p[i], est_m.p_W_B[j] - est_m.p_W_B[i])
        t_err = np.einsum("nji,nj->ni", dR_q, dt_p - dt_q)  # translation of E, R_q,rel⁻¹ (Δ)
        tr = error_statistics(np.linalg.norm(t_err, axis=1))
        rot = error_statistics(rotation_angle_deg(np.einsum("nji,njk->nik", dR_q, dR_p)))
        out.append(
            RpeResult(
                float(d), int(i.size), tr["rmse"], tr["mean"], tr["median"], tr["max"],
                rot["rmse"], rot["mean"],
            )
        )  # fmt: skip
    return out
