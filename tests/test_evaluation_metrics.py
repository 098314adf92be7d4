"""ATE/RPE on the EuRoC ground truth: equality with evo's own pipeline (evo, GPL-3, is a test-only
oracle; tests/test_metrics_vs_evo.py checks every figure on random trajectories), an independent
numpy computation, and the 4-DoF posyaw alignment recovering a known yaw + translation."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core import sync as evo_sync
from evo.core.trajectory import PoseTrajectory3D

from svains.datasets import load_dataset
from svains.datasets.trajectory import write_tum
from svains.errors import ConfigError
from svains.evaluation.alignment import align_posyaw, rotation_about_axis
from svains.evaluation.metrics import ate, rpe
from svains.evaluation.report import ate_vs_groundtruth, evaluate_files
from svains.geometry.rotation import quat_multiply, rotmat_to_quat, so3_exp


@pytest.fixture(scope="module")
def gt(euroc_micro: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    g = load_dataset(euroc_micro).groundtruth
    return g.t_ns, g.p_W_B, g.q_W_B_wxyz


def perturb(
    t: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    R: np.ndarray,
    tr: np.ndarray,
    sigma: float,
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigidly move a trajectory (p' = R p + tr, q' = q_R ⊗ q) and add position noise."""
    rng = np.random.default_rng(seed)
    p2 = p @ R.T + tr + rng.normal(scale=sigma, size=p.shape)
    q2 = quat_multiply(rotmat_to_quat(R), q)
    return t.copy(), p2, q2


def umeyama_numpy(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent rigid least-squares fit dst ≈ R src + t (Kabsch/Umeyama via SVD)."""
    ms, md = src.mean(0), dst.mean(0)
    H = (dst - md).T @ (src - ms)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return R, md - R @ ms


def test_posyaw_recovers_known_yaw_and_translation() -> None:
    rng = np.random.default_rng(0)
    p = rng.normal(size=(200, 3)) * [5.0, 3.0, 1.0]
    for up in ([0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [0.3, 0.2, 0.93]):
        u = np.array(up) / np.linalg.norm(up)
        R = rotation_about_axis(u, 2.5)
        t = np.array([1.0, -4.0, 2.0])
        T = align_posyaw(p, p @ R.T + t, up_W=u)
        np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
        np.testing.assert_allclose(T[:3, 3], t, atol=1e-12)


def test_posyaw_is_least_squares_optimum() -> None:
    from scipy.optimize import minimize

    rng = np.random.default_rng(1)
    p = rng.normal(size=(100, 3)) * 4
    ref = p @ rotation_about_axis([0, 0, 1], -0.8).T + [3.0, 1.0, -2.0]
    ref += rng.normal(scale=0.3, size=ref.shape)
    T = align_posyaw(p, ref)

    def cost(x: np.ndarray) -> float:
        return float(np.sum((p @ rotation_about_axis([0, 0, 1], x[0]).T + x[1:] - ref) ** 2))

    best = minimize(cost, np.zeros(4), method="BFGS", options={"gtol": 1e-10})
    ours = float(np.sum((p @ T[:3, :3].T + T[:3, 3] - ref) ** 2))
    assert ours <= best.fun + 1e-9
    assert np.arctan2(T[1, 0], T[0, 0]) == pytest.approx(best.x[0], abs=1e-6)


def test_se3_ate_equals_evo_and_numpy(gt: tuple) -> None:
    t, p, q = gt
    R = so3_exp([0.3, -0.2, 1.1])
    te, pe, qe = perturb(t, p, q, R, np.array([2.0, -1.0, 0.5]), 0.05, seed=42)
    res = ate(te, pe, qe, t, p, q, align="se3")
    # evo's own pipeline, as evo_ape would run it.
    ref = PoseTrajectory3D(p, q, t * 1e-9)
    est = PoseTrajectory3D(pe, qe, te * 1e-9)
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=0.01)
    est = copy.deepcopy(est)
    est.align(ref)
    m = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    m.process_data((ref, est))
    # numpy, not evo, computes them now: equal to rounding.
    assert res.rmse == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)
    assert res.max == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.max), rel=1e-9)
    m_rot = evo_metrics.APE(evo_metrics.PoseRelation.rotation_angle_deg)
    m_rot.process_data((ref, est))
    assert res.rot_rmse_deg == pytest.approx(
        m_rot.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9, abs=1e-9
    )
    assert res.rot_rmse_deg > 0.01  # the noise-free attitudes still see the fitted rotation
    # Independent numpy computation.
    Rn, tn = umeyama_numpy(pe, p)
    err = np.linalg.norm(pe @ Rn.T + tn - p, axis=1)
    assert res.rmse == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-9)
    assert res.median == pytest.approx(np.median(err), rel=1e-9)
    # Noise is 0.05 m per axis: the 3-D error RMS is about 0.05 * sqrt(3).
    assert res.rmse == pytest.approx(0.05 * np.sqrt(3), rel=0.05)
    assert res.n == t.size
    np.testing.assert_allclose(res.T_align[:3, :3], R.T, atol=2e-3)
    np.testing.assert_allclose(res.p_est_aligned, pe @ Rn.T + tn, atol=1e-9)


def test_none_and_sim3(gt: tuple) -> None:
    t, p, q = (a[::4] for a in gt)
    te, pe, qe = perturb(t, p, q, np.eye(3), np.array([0.3, 0.4, 0.0]), 0.0, seed=0)
    assert ate(te, pe, qe, t, p, q, align="none").rmse == pytest.approx(0.5, abs=1e-12)
    assert ate(te, pe, qe, t, p, q, align="se3").rmse == pytest.approx(0.0, abs=1e-9)
    pe2 = 2.0 * p + [1.0, 0.0, 0.0]
    r = ate(t, pe2, q, t, p, q, align="sim3")
    assert r.scale == pytest.approx(0.5, rel=1e-9) and r.rmse == pytest.approx(0.0, abs=1e-9)
    assert ate(t, pe2, q, t, p, q, align="se3").rmse > 0.1


def test_posyaw_ate_yaw_only_perturbation(gt: tuple) -> None:
    t, p, q = (a[::4] for a in gt)
    te, pe, qe = perturb(t, p, q, so3_exp([0, 0, 0.9]), np.array([1.0, 2.0, 3.0]), 0.0, seed=0)
    r = ate(te, pe, qe, t, p, q, align="posyaw")
    assert r.rmse == pytest.approx(0.0, abs=1e-9)
    assert r.rot_rmse_deg == pytest.approx(0.0, abs=1e-5)
    # A roll error cannot be absorbed by a yaw: posyaw leaves a residual, se3 does not.
    te, pe, qe = perturb(t, p, q, so3_exp([0.2, 0, 0]), np.zeros(3), 0.0, seed=0)
    assert ate(te, pe, qe, t, p, q, align="posyaw").rmse > 0.05
    assert ate(te, pe, qe, t, p, q, align="se3").rmse == pytest.approx(0.0, abs=1e-9)


def test_association_subsampled_and_jittered(gt: tuple) -> None:
    t, p, q = gt
    idx = np.arange(0, t.size, 3)
    jitter = np.random.default_rng(5).integers(-4_000_000, 4_000_000, idx.size)
    r = ate(t[idx] + jitter, p[idx], q[idx], t, p, q, align="none")
    assert r.n == idx.size and r.rmse == 0.0
    np.testing.assert_array_equal(r.t_ns, t[idx] + jitter)
    with pytest.raises(ConfigError, match=r"no matching timestamps within 0\.01 s"):
        ate(t + 25_000_000, p, q, t, p, q)


def test_rpe(gt: tuple) -> None:
    t, p, q = gt
    te, pe, qe = perturb(t, p, q, so3_exp([0.1, 0.5, -1.0]), np.array([5.0, 0, 0]), 0.0, seed=0)
    rigid = rpe(te, pe, qe, t, p, q, delta_m=[1.0, 2.0])
    assert [r.delta_m for r in rigid] == [1.0, 2.0]
    assert all(r.n_pairs > 10 and r.trans_rmse < 1e-9 for r in rigid)
    _, pn, qn = perturb(t, p, q, np.eye(3), np.zeros(3), 0.02, seed=7)
    noisy = rpe(t, pn, qn, t, p, q, delta_m=[1.0])[0]
    # Relative error of two independent 2 cm noises, rotated: about 0.02 * sqrt(6) m RMS.
    assert noisy.trans_rmse == pytest.approx(0.02 * np.sqrt(6), rel=0.25)
    far = rpe(t, p, q, t, p, q, delta_m=[1e6])[0]
    assert far.n_pairs == 0 and np.isnan(far.trans_rmse)
    with pytest.raises(ConfigError, match="segment length must be positive"):
        rpe(t, p, q, t, p, q, delta_m=[0.0])


def test_bad_alignment_name(gt: tuple) -> None:
    t, p, q = gt
    with pytest.raises(ConfigError, match="unknown alignment 'yaw'"):
        ate(t, p, q, t, p, q, align="yaw")  # type: ignore[arg-type]


def test_evaluate_files_tum_against_dataset(tmp_path: Path, euroc_micro: Path, gt: tuple) -> None:
    t, p, q = gt
    te, pe, qe = perturb(t, p, q, so3_exp([0, 0, 0.4]), np.array([1.0, 1.0, 0]), 0.01, seed=3)
    write_tum(tmp_path / "est.tum", te, pe, qe)
    rep = evaluate_files(tmp_path / "est.tum", euroc_micro, align="posyaw", delta_m=[1.0])
    direct = ate(te, pe, qe, t, p, q, align="posyaw")
    assert rep.ate.rmse == direct.rmse
    g = load_dataset(euroc_micro).groundtruth
    assert ate_vs_groundtruth(te, pe, qe, g, align="posyaw").rmse == direct.rmse
    d = rep.to_dict()
    assert d["ate"]["alignment"] == "posyaw" and d["rpe"][0]["delta_m"] == 1.0
    rep.to_json(tmp_path / "out.json")
    assert '"rmse"' in (tmp_path / "out.json").read_text()
