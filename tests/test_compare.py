"""Comparison helpers (outages, alignment, table) and figures on synthetic runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets.types import Dataset, FeatureStream, GpsStream, GroundTruth
from svains.evaluation.accuracy import gps_outage_report
from svains.evaluation.compare import (
    align_to_groundtruth,
    comparison_markdown,
    frame_rows,
    gps_outages,
    outage_max_errors,
    trajectory_metrics,
)
from svains.evaluation.figures import comparison_figures
from svains.geometry.rotation import so3_exp
from svains.navigation.outputs import RunResult


def _truth(n: int = 201) -> GroundTruth:
    t = np.linspace(0, 20, n)
    p = np.column_stack([10 * np.cos(0.3 * t), 6 * np.sin(0.3 * t), 2 + 0.1 * t])
    v = np.gradient(p, t, axis=0)
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    z = np.zeros((n, 3))
    return GroundTruth((t * 1e9).astype(np.int64), p, q, v, z, z)


def _dataset(gt: GroundTruth) -> Dataset:
    t_gps = np.arange(0, 21, 1.0)
    t_gps = t_gps[(t_gps < 5) | (t_gps > 9)]  # one outage 4 s -> 10 s
    gps = GpsStream((t_gps * 1e9).astype(np.int64), np.zeros((len(t_gps), 3)),
                    np.zeros((len(t_gps), 3)))
    return Dataset(root=Path("memory"), name="synthetic", groundtruth=gt, gps=gps)


def _run(gt: GroundTruth, offset: np.ndarray, method: str) -> RunResult:
    n = len(gt.t_ns)
    x = np.zeros((n, 13))
    x[:, 0:3] = gt.p_W_B + offset
    x[:, 3:6] = gt.v_W_B
    x[:, 6:10] = gt.q_W_B_wxyz
    return RunResult(gt.t_ns, x, np.full((n, 12), 0.1), np.tile(np.eye(9), (n, 1, 1)),
                     {"method": method, "realtime_factor": 10.0})


def test_gps_outage_detected_and_max_error_inside() -> None:
    gt = _truth()
    ds = _dataset(gt)
    assert gps_outages(ds) == [(4_000_000_000, 10_000_000_000)]
    x = gt.p_W_B.copy()
    bump = (gt.t_ns >= 6e9) & (gt.t_ns <= 7e9)
    x[bump, 0] += 0.7
    x[gt.t_ns > 15e9, 1] += 3.0  # outside the outage: must not count
    # The state logged at the first fix after the outage is the one that fix corrected: its
    # error (here a noisy fix's 2 m) is not the outage's, for compare as for run's report.
    x[gt.t_ns == 10_000_000_000, 2] += 2.0
    assert (gt.t_ns == 10_000_000_000).sum() == 1
    (err,) = outage_max_errors(gt.t_ns, x, gt, gps_outages(ds))
    assert err == pytest.approx(0.7)
    xs = np.zeros((len(gt.t_ns), 13))
    xs[:, 0:3] = x
    report = gps_outage_report(gt.t_ns, xs, np.full((len(gt.t_ns), 12), 0.1), ds.gps.t_ns, gt)
    assert [o["error_max_m"] for o in report["gps_outages"]] == [pytest.approx(err)]


def test_outage_report_counts_a_start_without_fixes_and_a_run_without_any() -> None:
    gt = _truth()
    xs = np.zeros((len(gt.t_ns), 13))
    xs[:, 0:3] = gt.p_W_B + np.array([0.5, 0.0, 0.0])
    std = np.full((len(gt.t_ns), 12), 0.1)
    # GPS only from 8 s on: 0-8 s is an outage too, not "position with GPS".
    late = (np.arange(8, 21, 1.0) * 1e9).astype(np.int64)
    xs[gt.t_ns < 8e9, 0] += 2.0
    rep = gps_outage_report(gt.t_ns, xs, std, late, gt)
    (first,) = rep["gps_outages"]
    assert first["from_start"] is True and "to_end" not in first
    assert first["start_s"] == 0.0 and first["duration_s"] == pytest.approx(8.0)
    assert first["error_max_m"] == pytest.approx(2.5)
    assert rep["position_rmse_with_gps_m"] == pytest.approx(0.5)
    # No fix at all (``--gps-outage`` over the whole run): no RMSE "with GPS", one outage.
    none = gps_outage_report(gt.t_ns, xs, std, np.zeros(0, np.int64), gt)
    assert none["position_rmse_with_gps_m"] is None
    (whole,) = none["gps_outages"]
    assert whole["from_start"] is True and whole["to_end"] is True
    assert whole["duration_s"] == pytest.approx(20.0, abs=1e-6)


def _run_at(gt: GroundTruth, p_W_B: np.ndarray, method: str) -> RunResult:
    r = _run(gt, np.zeros(3), method)
    r.x[:, 0:3] = p_W_B
    return r


def test_alignments_remove_the_right_degrees_of_freedom() -> None:
    gt = _truth()
    ds = _dataset(gt)
    rng = np.random.default_rng(0)
    R_yaw = so3_exp(np.array([0.0, 0.0, 0.4]))
    moved = gt.p_W_B @ R_yaw.T + np.array([3.0, -2.0, 1.0])
    res = align_to_groundtruth(_run_at(gt, moved, "3d"), ds, "posyaw")
    assert res is not None and res.alignment == "posyaw"
    np.testing.assert_allclose(res.p_est_aligned, gt.p_W_B, atol=1e-9)
    assert res.rmse < 1e-9
    R_any = so3_exp(rng.normal(0, 0.3, 3))
    moved = gt.p_W_B @ R_any.T + 1.0
    res = align_to_groundtruth(_run_at(gt, moved, "vo"), ds, "se3")
    assert res is not None
    np.testing.assert_allclose(res.p_est_aligned, gt.p_W_B, atol=1e-9)
    # A roll/pitch error is NOT removed by the 4-DoF alignment.
    R_roll = so3_exp(np.array([0.2, 0.0, 0.0]))
    res = align_to_groundtruth(_run_at(gt, gt.p_W_B @ R_roll.T, "3d"), ds, "posyaw")
    assert res is not None and res.max > 0.1


def test_straight_run_falls_back_to_no_alignment() -> None:
    n = 50
    t = np.linspace(0, 5, n)
    p = np.column_stack([2.0 * t, np.zeros(n), np.full(n, 2.0)])
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    z = np.zeros((n, 3))
    gt = GroundTruth((t * 1e9).astype(np.int64), p, q, np.tile([2.0, 0, 0], (n, 1)), z, z)
    ds = Dataset(root=Path("memory"), name="line", groundtruth=gt)
    r = _run_at(gt, p + np.array([0.0, 0.3, 0.4]), "vo")
    r.world_frame = "local"  # VO in its own frame: se3, which a straight line leaves undetermined
    m = trajectory_metrics(r, ds, "vo", False)
    assert m["ate_alignment"] == "none"
    assert m["ate_m"] == pytest.approx(0.5)


def test_trajectory_metrics_and_table() -> None:
    gt = _truth()
    ds = _dataset(gt)
    r = _run(gt, np.array([0.3, 0.0, 0.4]), "3d")
    m = trajectory_metrics(r, ds, "3d", gps_used=True)
    assert m["ate_alignment"] == "none"
    assert m["ate_m"] == pytest.approx(0.5)
    assert m["outage_max_error_m"] == [pytest.approx(0.5)]
    assert m["final_error_pct_of_path"] == pytest.approx(100 * 0.5 / m["path_length_m"])
    m_denied = trajectory_metrics(r, ds, "3d", gps_used=False)
    assert m_denied["ate_alignment"] == "posyaw" and m_denied["ate_m"] < 1e-9
    assert "outage_max_error_m" not in m_denied
    r.report.update(m)
    md = comparison_markdown({"3d": r.report, "lc": {"error": "no egomotion"}}, "t")
    assert "| 3d | 0.500 | none |" in md and "| lc | failed: no egomotion |" in md


def test_final_error_of_a_static_start_without_gps_is_taken_after_alignment() -> None:
    # A local world frame (static start, no GPS): yaw and position are arbitrary, so the final
    # error is measured after the ATE's posyaw alignment; a ground-truth start keeps it raw.
    gt = _truth()
    ds = Dataset(root=Path("memory"), name="synthetic", groundtruth=gt)
    moved = gt.p_W_B @ so3_exp(np.array([0.0, 0.0, 0.7])).T + np.array([3.0, -2.0, 1.0])
    r = _run_at(gt, moved, "3d")
    raw = trajectory_metrics(r, ds, "3d", gps_used=False)
    assert raw["final_position_error_m"] > 3.0
    r.world_frame = "local"
    local = trajectory_metrics(r, ds, "3d", gps_used=False)
    assert local["ate_alignment"] == "posyaw" and local["final_position_error_m"] < 1e-9
    assert local["ate_m"] == pytest.approx(raw["ate_m"], abs=1e-12)


def test_figures_are_written(tmp_path: Path) -> None:
    gt = _truth()
    ds = _dataset(gt)
    runs = {m: _run(gt, np.array([0.1 * i, 0, 0]), m) for i, m in enumerate(("lc", "tc", "3d"))}
    vo = _run(gt, np.zeros(3), "vo")
    vo.report["vo"] = {"break_t_ns": [int(gt.t_ns[50])]}
    runs["vo"] = vo
    for m, r in runs.items():
        r.report.update(trajectory_metrics(r, ds, m, gps_used=True))
    paths = comparison_figures(ds, runs, tmp_path)
    names = sorted(p.name for p in paths)
    assert names == ["fig10_tc.png", "fig11_3d.png", "fig5.png", "fig7_vo.png", "fig9_lc.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_vo_is_aligned_like_the_filters_when_it_starts_from_the_true_pose() -> None:
    from svains.evaluation.compare import ate_alignment

    assert ate_alignment("vo", gps_used=False, world_frame="groundtruth") == "posyaw"
    assert ate_alignment("vo", gps_used=False, world_frame="local") == "se3"
    assert ate_alignment("3d", gps_used=False) == "posyaw"
    assert ate_alignment("3d", gps_used=True) == "none"


def test_frame_rows_picks_the_output_pose_at_each_recorded_frame() -> None:
    """``ate_frames_m``'s rows: outputs at 10 Hz, stereo frames at 2 Hz 1 ms after an output
    (matched), one frame 30 ms from any output (not matched); none without ``features0``."""
    t_out = np.arange(0, 3_000_000_000, 100_000_000, dtype=np.int64)  # 0 .. 2.9 s
    frames = np.array([1, 500, 1000, 1500, 2030, 2500], np.int64) * 1_000_000 + 1_000_000
    fs = FeatureStream(t_ns=np.repeat(frames, 2), track_id=np.tile([0, 1], frames.size),
                       uv_left=np.zeros((2 * frames.size, 2)),
                       uv_right=np.zeros((2 * frames.size, 2)), pixel_noise_std=0.5)  # fmt: skip
    ds = Dataset(root=Path("memory"), name="frames", features=fs)
    rows = frame_rows(t_out, ds)
    assert rows is not None
    np.testing.assert_array_equal(rows, [0, 5, 10, 15, 25])
    assert frame_rows(t_out, Dataset(root=Path("memory"), name="none", features=None)) is None


def test_runs_without_what_they_were_asked_for_fail_the_comparison(tmp_path: Path) -> None:
    """A vision method that fused no vision looked like a result (its row was the INS run's)
    and vo that linked no frames gave a row of dashes, with exit 0 (a user's probe). Now each
    row says so and the command exits 1 unless --allow-degraded; ``svains run --method vo``
    too. Each method's folder holds its config.yaml."""
    import logging

    from typer.testing import CliRunner

    from svains.cli.main import app
    from svains.evaluation.compare import comparison_markdown, degraded_note
    from test_datasets_roundtrip import write_full

    assert degraded_note({"method": "vo", "vo": {"frames": 4, "breaks": 3}}) == (
        "no motion: 4 frame(s), none linked to the one before")
    assert degraded_note({"method": "vo", "vo": {"frames": 4, "breaks": 2}}) is None
    assert degraded_note({"method": "tc", "vision_degraded": True}) == "no vision fused: plain INS"
    md = comparison_markdown({"tc": {"vision_degraded": True, "ate_m": 0.2}}, "t")
    assert "| tc (no vision fused: plain INS) | 0.200 |" in md
    write_full(tmp_path / "ds")  # 4 frames of 32x24 noise: every one a tracking break
    logging.disable(logging.CRITICAL)
    try:
        runner = CliRunner()
        res = runner.invoke(app, ["run", str(tmp_path / "ds"), "--method", "vo", "--images",
                                  "--out", str(tmp_path / "o")])  # fmt: skip
        assert res.exit_code == 1
        assert ("vo estimated no motion: 4 frame(s), none linked to the one before"
                in res.stderr)  # fmt: skip
        args = ["compare", str(tmp_path / "ds"), "--methods", "ins,vo", "--images",
                "--out", str(tmp_path / "c"), "--no-figures"]  # fmt: skip
        res = runner.invoke(app, args)
        assert res.exit_code == 1
        assert ("1 of 2 method(s) failed: vo (no motion: 4 frame(s), none linked to the one "
                "before) (--allow-degraded accepts them)") in res.stderr
        assert "| vo | no motion: 4 frame(s)" in (tmp_path / "c" / "compare.md").read_text()
        assert (tmp_path / "c" / "ins" / "config.yaml").read_text().count("method: ins") == 1
        res = runner.invoke(app, [*args, "--force", "--allow-degraded"])
        assert res.exit_code == 0, res.stderr
    finally:
        logging.disable(logging.NOTSET)
