"""End to end: the simulator's village (features only) through every method and ``compare``."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.datasets.loader import load_dataset
from svains.evaluation.compare import run_methods, write_comparison
from svains.navigation.options import InitOptions, RunOptions
from svains.sim import SimConfig, simulate


@pytest.fixture(scope="module")
def village_denied(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """15 s GPS-denied village flight, stereo 5 Hz, features only (no images)."""
    cfg = SimConfig()
    cfg = replace(
        cfg, duration_s=15.0, seed=3,
        camera=replace(cfg.camera, rate_hz=5.0, render_images=False),
        gps=replace(cfg.gps, enabled=False), mag=replace(cfg.mag, enabled=False),
    )
    return simulate(cfg, tmp_path_factory.mktemp("village") / "ds")


@pytest.mark.slow
def test_all_methods_beat_pure_inertial_when_gps_denied(
    village_denied: Path, tmp_path: Path
) -> None:
    ds = load_dataset(village_denied)
    opts = RunOptions(model="biased", init=InitOptions(mode="groundtruth"))  # default vision
    res = run_methods(ds, ("ins", "vo", "lc", "tc", "3d"), opts, tmp_path)
    final = {m: r.report["final_position_error_m"] for m, r in res.items()}
    ate = {m: r.report["ate_m"] for m, r in res.items()}
    # Measured 2026-12-03 (seed 3, 15 s, default clone model), final error / ATE [m]: ins
    # 16.0 / 2.17, vo 0.274 / 0.082 with RANSAC's egomotion and 0.017 ATE with the two-frame
    # bundle adjustment (vo's default since), lc 0.309 / 0.086, tc = 3d 0.120 / 0.027.
    for m in ("vo", "lc", "tc", "3d"):
        assert final[m] < 0.05 * final["ins"], final
    # The paper's ordering where it must hold: the tightly coupled 3d well ahead of lc (measured
    # 3.2x; with --rotation imu it was not: 3d 0.140 against vo 0.082, unnoticed). The paper's
    # vo is RANSAC's; ours is bundle-adjusted and, on features0's exact white pixel noise,
    # beats 3d (see docs/results/low-rate.md "The two-frame bundle adjustment").
    assert ate["3d"] < 0.5 * ate["lc"], ate
    assert final["3d"] < 0.6 * final["lc"], final
    ransac_vo = replace(opts, vision=replace(opts.vision, egomotion_bundle=False))
    vo_plain = run_methods(ds, ("vo",), ransac_vo, tmp_path / "plain")["vo"].report["ate_m"]
    assert ate["3d"] < 0.5 * vo_plain, (ate, vo_plain)
    assert ate["vo"] < 0.4 * vo_plain, (ate, vo_plain)
    assert res["3d"].report["final_error_pct_of_path"] < 5.0, final
    # For a rectified pair the trifocal transfer equals reprojecting the eq.-10 point: TC == 3D.
    np.testing.assert_allclose(res["tc"].x, res["3d"].x, atol=1e-6)
    assert res["3d"].report["measurements"]["3d"]["fused"] >= 70  # of 74 frame pairs
    assert res["vo"].report["vo"]["breaks"] == 0
    reports = write_comparison(tmp_path, res, "test")
    data = json.loads((tmp_path / "compare.json").read_text())
    assert set(data) == {"ins", "vo", "lc", "tc", "3d"} == set(reports)
    # VO started from the true pose is aligned like the filters (its roll/pitch drift counts).
    assert data["3d"]["ate_alignment"] == "posyaw" and data["vo"]["ate_alignment"] == "posyaw"
    assert "| 3d |" in (tmp_path / "compare.md").read_text()
    for m in ("ins", "vo", "3d"):
        assert (tmp_path / m / "trajectory.tum").is_file()


@pytest.mark.slow
def test_compare_cli_writes_table_and_json(village_denied: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from svains.cli.main import app

    out = tmp_path / "cmp"
    result = CliRunner().invoke(app, [
        "compare", str(village_denied), "--out", str(out), "--methods", "3d",
        "--no-gps", "--no-mag", "--no-figures", "--set", "max_features=50",
    ])
    assert result.exit_code == 0, result.output
    data = json.loads((out / "compare.json").read_text())
    assert list(data) == ["3d"] and data["3d"]["ate_alignment"] == "posyaw"
    assert data["3d"]["ate_m"] < 0.04  # measured 0.0269 m (2026-12-02), limit 1.5x
    bad = CliRunner().invoke(app, ["compare", str(village_denied), "--out", str(tmp_path / "b"),
                                   "--methods", "3d", "--set", "pixel_sigma=1"])
    assert bad.exit_code == 2 and "unknown configuration key 'pixel_sigma'" in bad.output  # usage


@pytest.mark.slow
def test_correlated_pixels_fuse_every_pixel_in_both_pairs_without_counting_it_twice(
    village_denied: Path, tmp_path: Path
) -> None:
    """``vision.correlated_pixels`` (opt-in): every feature in every frame pair at its full
    variance, the noise two pairs share taken out of the second (``vision_correlated``).
    Measured 2026-12-06 (seed 3, 15 s, 5 Hz), ATE [m] / NEES / position NEES (3 dof): default
    0.0266 / 7.48 / 1.43; correlated 0.0170 / 7.13 / 2.28; the same with the correlation
    ignored (every pixel counted twice) 0.0241 / 8.67 / 3.78."""
    ds = load_dataset(village_denied)
    opts = RunOptions(model="biased", init=InitOptions(mode="groundtruth"))
    corr = replace(opts, vision=replace(opts.vision, correlated_pixels=True))
    default = run_methods(ds, ("3d",), opts, tmp_path / "default")["3d"].report
    rep = run_methods(ds, ("3d",), corr, tmp_path / "corr")["3d"].report
    assert default["vision"]["features_correlated"] == 0  # opt-in
    assert rep["vision"]["features_correlated"] > 3000, rep["vision"]
    assert rep["vision"]["frames_correlation_dropped"] == 0
    assert rep["ate_m"] < 0.75 * default["ate_m"], (rep["ate_m"], default["ate_m"])
    assert rep["nees_blocks"]["position"] < 3.0, rep["nees_blocks"]


def test_vo_tracking_breaks_are_warned(
    village_denied: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Breaks (frames without a motion, bridged at the last one) were only a count in
    `report.json` (a user's probe: KITTI raw at every 10th pair, 3 breaks, 74 % of the path off,
    exit 0 and not a word)."""
    import svains.replay.vo as vo

    frames = vo._frame_tracks

    def losing_two(*args: object, **kw: object):  # type: ignore[no-untyped-def]
        for k, (t, tr) in enumerate(frames(*args, **kw)):  # type: ignore[arg-type]
            yield t, (replace(tr, egomotion=None) if tr is not None and k in (20, 40) else tr)

    monkeypatch.setattr(vo, "_frame_tracks", losing_two)
    opts = RunOptions(init=InitOptions(mode="groundtruth"))
    opts = replace(opts, vision=replace(opts.vision, source="features"))
    with caplog.at_level("WARNING"):
        res = vo.run(load_dataset(village_denied), opts)
    assert res.report["vo"]["breaks"] == 2
    assert "vo: tracking broke at 2 of" in caplog.text
