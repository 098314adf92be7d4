"""svains' trajectory metrics (numpy only) against evo, their oracle: evo is GPL-3, so it is a
test dependency only (the ``test`` extra) and the library never imports it.

On seeded random trajectories (noisy, scaled, sampled at other times or rates, unsorted, with
unnormalised quaternions) every figure of :mod:`svains.evaluation.metrics` equals evo's to 1e-9:
association, Umeyama se3/sim3 (reflection case included), the APE statistics, attitude errors
and the RPE. evo has no 4-DoF alignment: ``posyaw`` is checked against an independent fit (a
complex-number least squares in the horizontal plane) whose poses go through evo's APE.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from evo.core import geometry as evo_geometry
from evo.core import metrics as evo_metrics
from evo.core import sync as evo_sync
from evo.core.filters import FilterException
from evo.core.trajectory import PoseTrajectory3D
from scipy.spatial.transform import Rotation

from svains.errors import AlignmentError, ConfigError
from svains.evaluation import metrics
from svains.geometry.rotation import quat_exp

Traj = tuple[np.ndarray, np.ndarray, np.ndarray]  # t_ns (N,), p_W_B (N, 3) m, q_W_B_wxyz (N, 4)
T0_NS = 1_403_636_579_763_555_584  # EuRoC-like epoch: seconds as float64 keep ~0.2 µs
STATS = ("rmse", "mean", "median", "std", "min", "max")
REL = 1e-9


# --- trajectories ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Motion:
    """A smooth random body motion, a function of time: sums of sinusoids for the position (m,
    mostly horizontal, metres of amplitude) and for the rotation vector (rad)."""

    f: np.ndarray  # (2, 3, 3) Hz: [position | rotation], axis, component
    a: np.ndarray  # (2, 3, 3) amplitudes
    phi: np.ndarray  # (2, 3, 3) rad

    @staticmethod
    def random(rng: np.random.Generator) -> Motion:
        scale = np.array([[[6.0], [4.0], [0.5]], [[0.3], [0.3], [2.0]]])
        a = rng.uniform(0.5, 1.0, (2, 3, 3)) * scale
        return Motion(rng.uniform(0.02, 0.15, (2, 3, 3)), a, rng.uniform(0, 2 * np.pi, (2, 3, 3)))

    def sample(self, t_ns: np.ndarray) -> Traj:
        s = (np.asarray(t_ns) - T0_NS) * 1e-9
        arg = 2 * np.pi * self.f[..., None] * s + self.phi[..., None]  # (2, 3, 3, N)
        x = np.sum(self.a[..., None] * np.sin(arg), axis=2)  # (2, 3, N)
        return np.asarray(t_ns, np.int64), x[0].T.copy(), quat_exp(x[1].T)


def stamps(rng: np.random.Generator, rate_hz: float, duration_s: float, start_s: float = 0.0,
           jitter_s: float = 0.0) -> np.ndarray:  # fmt: skip
    """Timestamps (ns) at ``rate_hz`` from ``start_s`` after T0, with uniform jitter."""
    k = np.arange(int(duration_s * rate_hz))
    s = start_s + k / rate_hz + rng.uniform(-jitter_s, jitter_s, k.size)
    return T0_NS + np.round(s * 1e9).astype(np.int64)


def perturbed(rng: np.random.Generator, traj: Traj, sigma_p: float, sigma_q: float,
              scale: float = 1.0, messy_quats: bool = False) -> Traj:  # fmt: skip
    """The trajectory moved by a random rigid transform (and ``scale``), plus position noise
    ``sigma_p`` m and attitude noise ``sigma_q`` rad per axis; ``messy_quats``: quaternions
    scaled by 0.9-1.1 and randomly negated (the same rotations, as trajectory files may hold)."""
    t, p, q = traj
    R = Rotation.random(random_state=int(rng.integers(1 << 31)))
    p2 = scale * R.apply(p) + rng.normal(0, 5, 3) + rng.normal(0, sigma_p, p.shape)
    r2 = R * Rotation.from_quat(q[:, [1, 2, 3, 0]]) * Rotation.from_rotvec(
        rng.normal(0, sigma_q, p.shape)
    )
    q2 = r2.as_quat()[:, [3, 0, 1, 2]]
    if messy_quats:
        q2 *= rng.uniform(0.9, 1.1, (len(q2), 1)) * rng.choice([-1.0, 1.0], (len(q2), 1))
    return t, p2, q2


@dataclass(frozen=True)
class Case:
    name: str
    est: Traj
    ref: Traj
    max_diff_s: float = 0.01


def _noisy(rng: np.random.Generator) -> Case:
    m = Motion.random(rng)
    ref = m.sample(stamps(rng, 100, 40))
    return Case("noisy", perturbed(rng, ref, 0.05, 0.01, messy_quats=True), ref)


def _scaled(rng: np.random.Generator) -> Case:
    m = Motion.random(rng)
    ref = m.sample(stamps(rng, 50, 40))
    return Case("scaled", perturbed(rng, ref, 0.03, 0.005, scale=0.8), ref)


def _time_offsets(rng: np.random.Generator) -> Case:
    # Estimate at 20 Hz, jittered by ±8 ms and 3 ms late, starting before and ending after the
    # reference (those poses find no partner); reference at 100 Hz.
    m = Motion.random(rng)
    ref = m.sample(stamps(rng, 100, 30, start_s=1.0))
    est = m.sample(stamps(rng, 20, 34, start_s=-0.003, jitter_s=0.008))
    return Case("time_offsets", perturbed(rng, est, 0.05, 0.01), ref)


def _unequal_rates(rng: np.random.Generator) -> Case:
    # Reference with fewer poses (so it is the one kept whole) but denser in its 10 s: several
    # of its poses pair with one estimated pose (repeated estimate indices).
    m = Motion.random(rng)
    ref = m.sample(stamps(rng, 100, 10, start_s=5.0, jitter_s=0.001))
    est = m.sample(stamps(rng, 30, 40))
    return Case("unequal_rates", perturbed(rng, est, 0.05, 0.02), ref, max_diff_s=0.05)


def _unsorted(rng: np.random.Generator) -> Case:
    # The denser estimate unsorted: evo falls back to a full nearest-time search.
    m = Motion.random(rng)
    ref = m.sample(stamps(rng, 25, 40))
    t, p, q = perturbed(rng, m.sample(stamps(rng, 100, 40, jitter_s=0.002)), 0.05, 0.01)
    k = rng.permutation(t.size)
    return Case("unsorted", (t[k], p[k], q[k]), ref)


CASES: list[Callable[[np.random.Generator], Case]] = [
    _noisy, _scaled, _time_offsets, _unequal_rates, _unsorted,
]  # fmt: skip


@pytest.fixture(scope="module", params=[(c, seed) for c in CASES for seed in (0, 1)],
                ids=lambda cs: f"{cs[0].__name__[1:]}-{cs[1]}")  # fmt: skip
def case(request: pytest.FixtureRequest) -> Case:
    make, seed = request.param
    return make(np.random.default_rng(seed))


# --- evo's pipeline, as evo_ape / evo_rpe run it -------------------------------------------


def evo_traj(traj: Traj) -> PoseTrajectory3D:
    t, p, q = traj
    return PoseTrajectory3D(positions_xyz=p, orientations_quat_wxyz=q, timestamps=t * 1e-9)


def evo_associated(c: Case) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    return evo_sync.associate_trajectories(evo_traj(c.ref), evo_traj(c.est), max_diff=c.max_diff_s)


def evo_ape(ref: PoseTrajectory3D, est: PoseTrajectory3D, relation: evo_metrics.PoseRelation
            ) -> evo_metrics.APE:  # fmt: skip
    m = evo_metrics.APE(relation)
    m.process_data((ref, est))
    return m


def assert_ate_equals_evo(
    res: metrics.AteResult, ref: PoseTrajectory3D, est: PoseTrajectory3D
) -> None:
    """Every figure of ``res`` against evo's APE of the aligned estimate ``est``."""
    trans = evo_ape(ref, est, evo_metrics.PoseRelation.translation_part)
    rot = evo_ape(ref, est, evo_metrics.PoseRelation.rotation_angle_deg)
    assert res.n == est.num_poses
    for k in STATS:
        assert getattr(res, k) == pytest.approx(trans.get_statistic(evo_metrics.StatisticsType(k)),
                                                rel=REL, abs=1e-12), k  # fmt: skip
    np.testing.assert_allclose(res.errors_m, trans.error, rtol=REL, atol=1e-12)
    assert res.rot_rmse_deg == pytest.approx(
        rot.get_statistic(evo_metrics.StatisticsType.rmse), rel=REL, abs=1e-9
    )
    np.testing.assert_array_equal(res.p_ref, ref.positions_xyz)
    np.testing.assert_allclose(res.p_est_aligned, est.positions_xyz, rtol=0, atol=1e-9)
    q_evo = est.orientations_quat_wxyz  # as given when nothing moved it: normalise
    q_evo = q_evo / np.linalg.norm(q_evo, axis=1, keepdims=True)
    sign = np.sign(np.sum(res.q_est_aligned_wxyz * q_evo, axis=1, keepdims=True))
    np.testing.assert_allclose(res.q_est_aligned_wxyz, sign * q_evo, rtol=0, atol=1e-9)


# --- association ----------------------------------------------------------------------------


def test_matching_time_indices_equal_evo_on_edge_cases() -> None:
    rng = np.random.default_rng(3)
    big = 1.4e9
    sets = [
        # A tie (0.01 from both neighbours: the earlier wins), exact max_diff, out of range.
        (np.array([0.01, 0.02, -0.01, -0.0100001, 0.03, 0.0300001, 0.5]), np.array([0.0, 0.02])),
        (np.array([5.0]), np.array([5.0])),
        (np.array([4.99, 5.0, 5.01, 5.02]), np.array([5.0])),
        (big + np.sort(rng.uniform(0, 10, 300)), big + np.sort(rng.uniform(0, 10, 200))),
        (big + rng.uniform(-1, 11, 300), big + np.arange(0, 10, 0.02)),  # unsorted first
        (big + rng.uniform(0, 10, 300), big + rng.uniform(0, 10, 200)),  # unsorted second
        (np.arange(0, 1, 0.01), np.arange(0, 1, 0.01) + 0.005),  # every one a near tie
        (np.array([1.0, 1.0, 2.0]), np.array([1.0, 1.0, 1.0, 3.0])),  # repeated stamps
        # Unsorted second: exact max_diff and a tie, resolved by array order.
        (np.array([0.01, -0.01, 0.04, 0.05]), np.array([0.02, 0.0, 0.03])),
    ]
    for t1, t2 in sets:
        for md in (0.0, 0.001, 0.01, 0.05):
            ours = metrics.matching_time_indices(t1, t2, md)
            theirs = evo_sync.matching_time_indices(t1, t2, md)
            assert ours[0].tolist() == list(theirs[0]), (t1[:3], md)
            assert ours[1].tolist() == list(theirs[1]), (t1[:3], md)


def test_association_equals_evo(case: Case) -> None:
    ref_m, est_m, idx = metrics.associate(
        metrics.to_trajectory(*case.est, "estimate"), metrics.to_trajectory(*case.ref, "reference"),
        case.max_diff_s,
    )  # fmt: skip
    evo_ref, evo_est = evo_associated(case)
    assert 10 < est_m.num_poses == evo_est.num_poses
    np.testing.assert_array_equal(est_m.t_s, evo_est.timestamps)
    np.testing.assert_array_equal(ref_m.t_s, evo_ref.timestamps)
    np.testing.assert_array_equal(est_m.p_W_B, evo_est.positions_xyz)
    np.testing.assert_array_equal(ref_m.p_W_B, evo_ref.positions_xyz)
    np.testing.assert_array_equal(case.est[1][idx], evo_est.positions_xyz)
    if case.name == "unequal_rates":
        assert np.unique(idx).size < idx.size  # the case does exercise repeated partners


def test_association_of_equally_long_trajectories_keeps_the_estimate_whole() -> None:
    # Same pose count: evo pairs each estimated pose with a reference one (not the reverse,
    # which here would pair the three first reference poses with one estimated pose).
    t_ref = T0_NS + np.array([0, 1, 2, 1000], dtype=np.int64) * 1_000_000
    t_est = T0_NS + np.array([0, 500, 900, 1000], dtype=np.int64) * 1_000_000
    p = np.arange(12.0).reshape(4, 3)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    c = Case("equal", (t_est, p, q), (t_ref, p + 1.0, q))
    ref_m, est_m, idx = metrics.associate(
        metrics.to_trajectory(*c.est), metrics.to_trajectory(*c.ref), c.max_diff_s
    )
    evo_ref, evo_est = evo_associated(c)
    assert idx.tolist() == [0, 3] and evo_est.num_poses == 2
    np.testing.assert_array_equal(ref_m.p_W_B, evo_ref.positions_xyz)
    np.testing.assert_array_equal(est_m.p_W_B, evo_est.positions_xyz)


def test_no_match_is_a_config_error_where_evo_raises() -> None:
    m = Motion.random(np.random.default_rng(0))
    ref = m.sample(stamps(np.random.default_rng(1), 50, 5))
    est = (ref[0] + 6_000_000_000, ref[1], ref[2])  # 6 s late, after the 5 s reference
    with pytest.raises(evo_sync.SyncException):
        evo_associated(Case("late", est, ref))
    with pytest.raises(ConfigError, match=r"no matching timestamps within 0\.01 s"):
        metrics.ate(*est, *ref)
    with pytest.raises(ConfigError, match=r"no matching timestamps within 0\.01 s"):
        metrics.rpe(*est, *ref)


# --- statistics and Umeyama -----------------------------------------------------------------


def test_error_statistics_equal_evo() -> None:
    rng = np.random.default_rng(11)
    for e in (rng.exponential(0.1, 1001), rng.exponential(0.1, 1000), np.array([0.3]),
              np.full(7, 0.25), rng.uniform(0, 1e3, 50)):  # fmt: skip
        oracle = evo_metrics.APE()
        oracle.error = e
        theirs = oracle.get_all_statistics()
        ours = metrics.error_statistics(e)
        assert set(ours) == set(theirs) == {*STATS, "sse"}
        for k, v in theirs.items():
            assert ours[k] == pytest.approx(v, rel=REL, abs=1e-15), k


def test_umeyama_equals_evo_including_reflections() -> None:
    rng = np.random.default_rng(5)
    mirror = np.diag([-1.0, 1.0, 1.0])
    reflections = 0
    for k in range(12):
        src = rng.normal(size=(200, 3)) * [5.0, 3.0, 0.2 if k % 2 else 1.0]
        dst = 1.3 * Rotation.random(random_state=k).apply(src) + rng.normal(size=3)
        if k >= 6:
            dst = dst @ mirror  # a mirrored set: the unconstrained fit would be a reflection
        dst += rng.normal(scale=0.05, size=dst.shape)
        U, _, Vt = np.linalg.svd((dst - dst.mean(0)).T @ (src - src.mean(0)))
        reflections += np.linalg.det(U @ Vt) < 0
        for with_scale in (False, True):
            R, t, s = metrics.umeyama_alignment(src, dst, with_scale)
            r_e, t_e, s_e = evo_geometry.umeyama_alignment(src.T, dst.T, with_scale)
            assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
            np.testing.assert_allclose(R, r_e, rtol=0, atol=1e-9)
            np.testing.assert_allclose(t, t_e, rtol=0, atol=1e-9)
            assert s == pytest.approx(s_e, rel=REL)
    assert reflections >= 6


def test_degenerate_positions_are_refused_where_evo_refuses() -> None:
    n = 30
    line = np.column_stack([np.linspace(0, 10, n), np.zeros(n), np.zeros(n)])
    same = np.tile([1.0, 2.0, 3.0], (n, 1))
    plane = np.column_stack([np.linspace(0, 10, n), np.sin(np.arange(n)), np.zeros(n)])
    for src, dst, refused in ((line, line + 1.0, True), (same, same, True), (line, same, True),
                              (plane, plane + 1.0, False)):  # fmt: skip
        if refused:
            with pytest.raises(evo_geometry.GeometryException):
                evo_geometry.umeyama_alignment(src.T, dst.T)
            with pytest.raises(AlignmentError, match="rank"):
                metrics.umeyama_alignment(src, dst)
        else:
            evo_geometry.umeyama_alignment(src.T, dst.T)
            metrics.umeyama_alignment(src, dst)
    t = T0_NS + np.arange(n, dtype=np.int64) * 100_000_000
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    with pytest.raises(AlignmentError, match=r"se3 alignment is undetermined .*rank.*posyaw"):
        metrics.ate(t, line, q, t, line + 1.0, q, align="se3")


# --- ATE ------------------------------------------------------------------------------------


@pytest.mark.parametrize("align", ["none", "se3", "sim3"])
def test_ate_equals_evo(case: Case, align: str) -> None:
    res = metrics.ate(*case.est, *case.ref, align=align, max_diff_s=case.max_diff_s)  # type: ignore[arg-type]
    ref, est = evo_associated(case)
    est = copy.deepcopy(est)
    R, t, s = np.eye(3), np.zeros(3), 1.0
    if align != "none":
        R, t, s = est.align(ref, correct_scale=align == "sim3")
    assert_ate_equals_evo(res, ref, est)
    np.testing.assert_allclose(res.T_align[:3, :3], R, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.T_align[:3, 3], t, rtol=0, atol=1e-9)
    assert res.scale == pytest.approx(s, rel=REL)
    np.testing.assert_array_equal(res.t_ns * 1e-9, est.timestamps)
    if case.name == "scaled" and align == "sim3":
        assert res.scale == pytest.approx(1 / 0.8, rel=0.01)


def test_ate_of_a_mirrored_trajectory_equals_evo() -> None:
    # A flat trajectory mirrored left-right: only the reflection fix keeps the fit a rotation
    # (about 180° out of the plane); the result must still be evo's.
    rng = np.random.default_rng(8)
    m = Motion.random(rng)
    t, p, q = m.sample(stamps(rng, 50, 40))
    p_flat = p * [1.0, 1.0, 0.02]
    est = (t, p_flat * [-1.0, 1.0, 1.0] + rng.normal(0, 0.02, p.shape), q)
    c = Case("mirrored", est, (t, p_flat, q))
    res = metrics.ate(*c.est, *c.ref, align="se3")
    ref_e, est_e = evo_associated(c)
    est_e = copy.deepcopy(est_e)
    R, _, _ = est_e.align(ref_e)
    assert np.linalg.det(R) == pytest.approx(1.0) and np.trace(R) < 0  # a half turn
    assert_ate_equals_evo(res, ref_e, est_e)


def independent_posyaw(est: PoseTrajectory3D, ref: PoseTrajectory3D, up: np.ndarray) -> np.ndarray:
    """4x4 least-squares yaw (about ``up``) + translation of est onto ref, from the horizontal
    positions as complex numbers: the angle is arg Σ conj(a) b of the centred points."""
    u = up / np.linalg.norm(up)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    a = est.positions_xyz - est.positions_xyz.mean(0)
    b = ref.positions_xyz - ref.positions_xyz.mean(0)
    za, zb = a @ e1 + 1j * (a @ e2), b @ e1 + 1j * (b @ e2)
    psi = np.angle(np.sum(np.conj(za) * zb))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(psi * u).as_matrix()
    T[:3, 3] = ref.positions_xyz.mean(0) - T[:3, :3] @ est.positions_xyz.mean(0)
    return T


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.2, -0.3, 0.93)], ids=["z", "tilted"])
def test_posyaw_ate_equals_independent_fit_through_evo(case: Case, up: tuple) -> None:
    res = metrics.ate(*case.est, *case.ref, align="posyaw", max_diff_s=case.max_diff_s, up_W=up)
    ref, est = evo_associated(case)
    T = independent_posyaw(est, ref, np.asarray(up))
    est = copy.deepcopy(est)
    est.transform(T)
    assert_ate_equals_evo(res, ref, est)
    np.testing.assert_allclose(res.T_align, T, rtol=0, atol=1e-9)


# --- RPE ------------------------------------------------------------------------------------


def test_rpe_equals_evo(case: Case) -> None:
    deltas = [0.5, 1.0, 3.0, 10.0, 1e6]
    ours = metrics.rpe(*case.est, *case.ref, delta_m=deltas, max_diff_s=case.max_diff_s)
    ref, est = evo_associated(case)
    for d, r in zip(deltas, ours, strict=True):
        out = {}
        for rel in (evo_metrics.PoseRelation.translation_part,
                    evo_metrics.PoseRelation.rotation_angle_deg):  # fmt: skip
            m = evo_metrics.RPE(rel, delta=d, delta_unit=evo_metrics.Unit.meters)
            try:
                m.process_data((ref, est))
            except FilterException:
                out[rel] = None
                continue
            out[rel] = (len(m.error), m.get_all_statistics())
        tr = out[evo_metrics.PoseRelation.translation_part]
        rot = out[evo_metrics.PoseRelation.rotation_angle_deg]
        assert r.delta_m == d
        if tr is None:
            assert rot is None and r.n_pairs == 0 and np.isnan(r.trans_rmse)
            assert d == 1e6  # the other lengths do find pairs on these 30-40 s trajectories
            continue
        assert r.n_pairs == tr[0] == rot[0] > 0
        figures = ((r.trans_rmse, tr[1]["rmse"]), (r.trans_mean, tr[1]["mean"]),
                   (r.trans_median, tr[1]["median"]), (r.trans_max, tr[1]["max"]),
                   (r.rot_rmse_deg, rot[1]["rmse"]), (r.rot_mean_deg, rot[1]["mean"]))  # fmt: skip
        for k, (a, b) in enumerate(figures):
            assert a == pytest.approx(b, rel=REL, abs=1e-12), (d, k)


def test_path_pairs_equal_evo_on_the_threshold() -> None:
    # Steps of exactly 0.25 m: a 1 m segment is reached exactly (>=), not one pose later.
    p = np.column_stack([0.25 * np.arange(41), np.zeros(41), np.zeros(41)])
    from evo.core.filters import filter_pairs_by_path

    poses = [np.block([[np.eye(3), x[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) for x in p]
    for d in (0.25, 0.5, 1.0, 0.9, 1.1, 2.6):
        i, j = metrics.path_pairs(p, d)
        assert list(zip(i.tolist(), j.tolist(), strict=True)) == filter_pairs_by_path(poses, d)


def test_pairs_at_max_diff_are_warned_as_decided_by_rounding(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A 10 Hz estimate 10 ms off a 20 Hz reference with the default 0.01 s: each pose's
    nearest difference is 10 ms to within rounding, evo kept 1157 of 1448 poses, the same in
    exact nanoseconds 578 (a user's probe): warned once; a --max-diff away from it is not."""
    from svains.evaluation.metrics import associate, to_trajectory

    t_ref = np.arange(200, dtype=np.int64) * 50_000_000 + 10**18
    t_est = t_ref[::2][:-1] + 10_000_000 + np.tile([-128, 128], 50)[:99]
    ref = to_trajectory(t_ref, np.zeros((200, 3)), np.tile([1.0, 0, 0, 0], (200, 1)))
    est = to_trajectory(t_est, np.zeros((99, 3)), np.tile([1.0, 0, 0, 0], (99, 1)))
    with caplog.at_level(logging.WARNING):
        associate(est, ref, 0.01)
    assert caplog.text.count("99 of 99 poses are 0.01 s from their nearest") == 1
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        associate(est, ref, 0.015)
        associate(est, ref, 0.01, warn_ambiguous=False)
    assert "decided by rounding" not in caplog.text
    # one pose on each side (the test indexed the one before past the start: IndexError)
    one = to_trajectory(t_ref[:1], np.zeros((1, 3)), np.tile([1.0, 0, 0, 0], (1, 1)))
    assert associate(one, one, 0.01)[2].tolist() == [0]
    # the same stamps on both sides with --max-diff 1 us: exact pairs, nothing to warn (a
    # review: "200 of 200 poses are 1e-06 s from their nearest")
    with caplog.at_level(logging.WARNING):
        associate(ref, ref, 1e-6)
    assert "decided by rounding" not in caplog.text
