"""``svains evaluate``: micro ground truth vs itself rotated, translated and noisy; the ATE
printed and written to JSON equals an independent numpy/scipy computation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from svains.cli.main import app
from svains.datasets import load_dataset
from svains.datasets.trajectory import write_groundtruth_tum, write_tum
from svains.evaluation.alignment import rotation_about_axis
from svains.geometry.rotation import quat_multiply, rotmat_to_quat, so3_exp

runner = CliRunner()


@pytest.fixture(scope="module")
def moved(euroc_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    gt = load_dataset(euroc_micro).groundtruth
    d = tmp_path_factory.mktemp("eval")
    rng = np.random.default_rng(2024)
    out = {"gt": gt, "dir": d}
    for name, R in (("se3", so3_exp([0.4, -0.3, 2.0])), ("yaw", so3_exp([0.0, 0.0, -1.2]))):
        p = gt.p_W_B @ R.T + [3.0, -2.0, 1.0] + rng.normal(scale=0.03, size=gt.p_W_B.shape)
        q = quat_multiply(rotmat_to_quat(R), gt.q_W_B_wxyz)
        write_tum(d / f"{name}.tum", gt.t_ns, p, q)
        out[name] = p
    write_groundtruth_tum(d / "gt.tum", gt)
    return out


def test_evaluate_se3_matches_numpy(moved: dict, euroc_micro: Path) -> None:
    d = moved["dir"]
    res = runner.invoke(
        app,
        ["evaluate", str(d / "se3.tum"), str(euroc_micro), "--align", "se3", "--json",
         str(d / "se3.json"), "--delta", "2"],
        env={"COLUMNS": "140"},
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    # Independent: Kabsch/Umeyama by SVD, then RMS of the residual distances.
    src, dst = moved["se3"], moved["gt"].p_W_B
    ms, md = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - md).T @ (src - ms))
    R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    rmse = np.sqrt(np.mean(np.sum((src @ R.T + md - R @ ms - dst) ** 2, axis=1)))
    got = json.loads((d / "se3.json").read_text())
    assert got["ate"]["rmse"] == pytest.approx(rmse, rel=1e-9)
    assert got["ate"]["n"] == 2895 and got["ate"]["alignment"] == "se3"
    assert got["rpe"][0]["delta_m"] == 2.0 and got["rpe"][0]["n_pairs"] > 10
    assert f"{rmse:.4f}" in res.output
    assert "2895 matched poses" in res.output


def test_evaluate_posyaw_matches_scipy(moved: dict) -> None:
    from scipy.optimize import minimize

    d = moved["dir"]
    res = runner.invoke(app, ["evaluate", str(d / "yaw.tum"), str(d / "gt.tum"), "--align",
                              "posyaw", "--json", str(d / "yaw.json")])  # fmt: skip
    assert res.exit_code == 0, res.output
    src, dst = moved["yaw"], moved["gt"].p_W_B

    def cost(x: np.ndarray) -> float:
        R = rotation_about_axis([0, 0, 1], x[0])
        return float(np.mean(np.sum((src @ R.T + x[1:] - dst) ** 2, axis=1)))

    x0 = np.array([1.0, 0.0, 0.0, 0.0])
    opts = {"xatol": 1e-10, "fatol": 1e-14, "maxiter": 20000, "maxfev": 20000}
    best = minimize(cost, x0, method="Nelder-Mead", options=opts)
    got = json.loads((d / "yaw.json").read_text())["ate"]
    assert got["rmse"] == pytest.approx(np.sqrt(best.fun), rel=1e-6)
    assert got["rmse"] == pytest.approx(0.03 * np.sqrt(3), rel=0.05)


def test_evaluate_none_alignment_sees_the_offset(moved: dict) -> None:
    d = moved["dir"]
    res = runner.invoke(app, ["evaluate", str(d / "yaw.tum"), str(d / "gt.tum"), "--align",
                              "none", "--json", str(d / "none.json")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((d / "none.json").read_text())["ate"]["rmse"] > 1.0


def test_evaluate_bad_inputs(moved: dict, tmp_path: Path) -> None:
    d = moved["dir"]
    res = runner.invoke(app, ["evaluate", str(d / "se3.tum"), str(d / "gt.tum"), "--align", "x"])
    assert res.exit_code == 2 and "'--align': must be one of se3, posyaw, none, sim3" in res.output
    res = runner.invoke(app, ["evaluate", str(tmp_path / "no.tum"), str(d / "gt.tum")])
    assert res.exit_code == 1 and "missing file" in res.output
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty/mav0").mkdir(parents=True)
    (tmp_path / "empty/mav0/body.yaml").write_text("%YAML:1.0\ncomment: no streams\n")
    res = runner.invoke(app, ["evaluate", str(d / "se3.tum"), str(tmp_path / "empty")])
    assert res.exit_code == 1 and "data set has no ground truth" in res.output


def test_se3_on_a_resting_vehicle_is_refused_in_one_line(tmp_path: Path) -> None:
    # A vehicle at rest: millimetres of reference motion against millimetres of error leave the
    # fitted rotation arbitrary (issue 23: 143° printed where the run's own report said 0.62°).
    rng = np.random.default_rng(4)
    t = np.arange(50, dtype=np.int64) * 100_000_000
    q = np.tile([1.0, 0.0, 0.0, 0.0], (50, 1))
    ref = 1e-3 * rng.standard_normal((50, 3))
    est = ref + 2e-3 * rng.standard_normal((50, 3))
    write_tum(tmp_path / "ref.tum", t, ref, q)
    write_tum(tmp_path / "est.tum", t, est, q)
    args = ["evaluate", str(tmp_path / "est.tum"), str(tmp_path / "ref.tum")]
    res = CliRunner().invoke(app, [*args, "--align", "se3"])
    assert res.exit_code == 1, res.output
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and "se3 alignment is undetermined" in err[0] and "posyaw" in err[0]
    assert CliRunner().invoke(app, [*args, "--align", "posyaw"]).exit_code == 0
    # A moving reference (metres) with the same error aligns as before.
    move = ref + np.column_stack([np.linspace(0, 5, 50), np.linspace(0, 2, 50), np.zeros(50)])
    write_tum(tmp_path / "ref.tum", t, move, q)
    write_tum(tmp_path / "est.tum", t, move + (est - ref), q)
    assert CliRunner().invoke(app, [*args, "--align", "se3"]).exit_code == 0


def test_a_fit_that_tilts_the_estimate_says_so(tmp_path: Path) -> None:
    # A 200 m straight drive whose height drifts 0.07 m/m (4°): se3 removes the drift by
    # tilting the whole estimate, so its rotation errors are the fit's, not the estimate's
    # (KITTI raw 3d: 6.95° after se3, 0.64° after posyaw). posyaw leaves the tilt alone.
    n = 400
    t_ns = (np.arange(n) * 50_000_000).astype(np.int64)
    x = np.linspace(0.0, 200.0, n)
    p_ref = np.column_stack([x, 0.5 * np.sin(x / 20.0), np.zeros(n)])
    p_est = p_ref + np.column_stack([np.zeros(n), np.zeros(n), 0.07 * x])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    write_tum(tmp_path / "ref.tum", t_ns, p_ref, q)
    write_tum(tmp_path / "est.tum", t_ns, p_est, q)
    args = ["evaluate", str(tmp_path / "est.tum"), str(tmp_path / "ref.tum")]
    se3 = runner.invoke(app, [*args, "--align", "se3", "--json", str(tmp_path / "a.json")])
    assert se3.exit_code == 0, se3.output
    tilt = json.loads((tmp_path / "a.json").read_text())["ate"]["fit_tilt_deg"]
    assert tilt == pytest.approx(np.degrees(np.arctan(0.07)), abs=0.05)
    assert "note: the se3 fit tilted the estimate by 4.00°" in se3.output
    posyaw = runner.invoke(app, [*args, "--align", "posyaw"])
    assert posyaw.exit_code == 0 and "tilted" not in posyaw.output


def test_the_fit_tilt_is_measured_about_the_world_up() -> None:
    """KITTI odometry's camera world has y down: a fit turning about y is a yaw there, not a
    tilt (a review: ``fit_tilt_deg`` read 5° of yaw as 5° of tilt)."""
    from svains.evaluation.metrics import ate
    from svains.geometry.rotation import quat_to_rotmat, rotmat_to_quat, so3_exp

    rng = np.random.default_rng(3)
    n = 200
    t_ns = (np.arange(n) * 100_000_000).astype(np.int64)
    p_ref = np.cumsum(rng.normal(0.0, 1.0, (n, 3)), axis=0)
    q_ref = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    R = so3_exp([0.0, np.radians(5.0), 0.0])
    p_est = p_ref @ R.T
    q_est = rotmat_to_quat(R @ quat_to_rotmat(q_ref))
    res = ate(t_ns, p_est, q_est, t_ns, p_ref, q_ref, align="se3")
    assert res.fit_tilt_deg == pytest.approx(5.0, abs=1e-6)  # a z-up world's tilt
    assert res.tilt_about_deg((0.0, -1.0, 0.0)) == pytest.approx(0.0, abs=1e-6)
    assert res.tilt_about_deg((1.0, 0.0, 0.0)) == pytest.approx(5.0, abs=1e-6)
