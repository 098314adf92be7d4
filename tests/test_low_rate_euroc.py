"""Issue 22: the paper's regime on a real MAV IMU. EuRoC V1_01 (real 200 Hz IMU, 145 s) with
features simulated along its ground truth at 5 Hz, GPS-denied, static start, the defaults and
every S-th frame only (``bench/low_rate.py`` prints the whole table)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def _run_logged(euroc_micro: Path, out: Path, method: str, stride: int) -> tuple[dict, str]:
    """The run's report and what it wrote to stderr (its warnings)."""
    svains = Path(sys.executable).with_name("svains")
    cmd = [str(svains), "run", str(euroc_micro), "--method", method, "--synthetic-features", "5",
           "--no-gps", "--no-mag", "--set", f"vision.frame_stride={stride}", "--out", str(out)]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return dict(json.loads((out / "report.json").read_text(encoding="utf-8"))), done.stderr


def _run(euroc_micro: Path, out: Path, method: str, stride: int) -> dict[str, Any]:
    return _run_logged(euroc_micro, out, method, stride)[0]


@pytest.fixture(scope="module")
def euroc_run_report(euroc_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    return _run(euroc_micro, tmp_path_factory.mktemp("s1") / "run", "3d", 1)


def test_frames_02_s_apart_are_accurate_and_consistent(euroc_run_report: dict) -> None:
    r = euroc_run_report
    # Measured 2026-12-02: ATE 0.037 m, NEES 6.7 (limits 1.5x; the targets 0.05 / 18).
    assert r["ate_rmse_m"] < 0.05
    assert r["nees_mean"] < 10.0
    # Per block (3/3/2/1 dof when consistent): 0.1 / 3.0 / 3.1 / 0.1; the platform noise
    # rule is what brought roll/pitch from 72 and velocity from 45 (issue 22).
    b = r["nees_blocks"]
    assert b["velocity"] < 4.5 and b["roll_pitch"] < 4.7
    assert r["vision"]["frames_fused"] >= 720
    assert r["measurements"]["zupt"]["fused"] > 30  # the 5 s rest before take-off


def test_frames_2_s_apart_neither_cascade_nor_diverge(euroc_micro: Path, tmp_path: Path) -> None:
    r, stderr = _run_logged(euroc_micro, tmp_path / "run", "3d", 10)
    # Measured 2026-12-02: ATE 0.098 m, NEES 8.8, 70 of 72 frames fused (before issue 22:
    # 29 m, 17 frames, the whole-frame gate refusing every frame after the first refusals).
    assert r["ate_rmse_m"] < 0.147
    assert r["nees_mean"] < 13.2
    assert r["vision"]["frames_fused"] >= 0.95 * r["vision"]["frames"]
    # The first frame (2 s in) cannot fuse alone: no "no vision fused" warning at 2.04 s while
    # the second is due (a user's probe), and the report's gaps take the warning's limit.
    assert "no vision fused" not in stderr
    assert r["vision_gap_limit_s"] == pytest.approx(5.0, rel=0.01) and r["vision_gaps"] == []


def test_frames_5_s_apart_run_to_the_end_without_diverging(
    euroc_micro: Path, tmp_path: Path
) -> None:
    # Measured 2026-12-02: ATE 0.861 m (the target: 1 m), NEES 14.3, 24 of 28 frames
    # fused, 11 through their egomotion (1.93 m without the wide-baseline RANSAC retry); before
    # issue 22: exit 1, covariance not PD.
    r = _run(euroc_micro, tmp_path / "run", "3d", 25)
    # Since the relocalisation (2026-12-05): 0.488 m, NEES 8.0, 27 of 28 fused, 12 through
    # their egomotion, 2 against a stored keyframe (frames that share nothing with the one
    # before, seen again from 20-60 s earlier); without it 0.860 m (limit 1.33x).
    # Since two-view frames over a wide prior are linearised at their egomotion (2026-12-05):
    # 0.507 m, NEES 9.8, 27 of 28 fused, none through the egomotion fallback (the pixels now
    # fit), 26 linearised at the egomotion.
    assert r["ate_rmse_m"] < 0.65
    assert r["nees_mean"] < 12.0
    assert r["vision"]["frames_linearised_at_egomotion"] >= 20
    assert r["vision"]["frames_fused"] >= 25
    assert r["vision"]["frames_relocalised"] >= 1
    assert 0 < r["vision"]["keyframes_stored"] <= 28


def test_lc_frames_5_s_apart_run_to_the_end(euroc_micro: Path, tmp_path: Path) -> None:
    # Before: exit 1 (an indefinite egomotion covariance from the front end). Measured: 1.42 m
    # with 17 of 28 frames fused; since the wider RANSAC retries (2026-12-03) 0.798 m, 23;
    # since the relocalisation (2026-12-05) 0.569 m, NEES 7.0, 26 (3 against stored keyframes).
    r = _run(euroc_micro, tmp_path / "run", "lc", 25)
    assert r["ate_rmse_m"] < 0.75
    assert r["vision"]["frames_fused"] >= 25
    assert r["vision"]["frames_relocalised"] >= 2
    assert r["vision"]["frames_bad_covariance"] >= 1


def test_a_lost_filter_says_so(euroc_micro: Path, tmp_path: Path) -> None:
    """The older `--rotation imu` model at every 15th frame (3 s) loses the filter (1110 m,
    exit 0): it said only that vision was missing and the filter inconsistent (a user's probe).
    Now one line says it is lost, and the report says when; the default model is not lost."""
    svains = Path(sys.executable).with_name("svains")
    out = tmp_path / "imu"
    cmd = [str(svains), "run", str(euroc_micro), "--method", "3d", "--synthetic-features", "5",
           "--no-gps", "--no-mag", "--set", "vision.frame_stride=15", "--rotation", "imu",
           "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    r = json.loads((out / "report.json").read_text(encoding="utf-8"))
    lost = r["recovery"]["lost"]
    assert r["ate_rmse_m"] > 100.0 and len(lost) == 1 and lost[0]["refusing"] == ["3d"]
    assert lost[0]["position_std_m"] > 10.0
    assert done.stderr.count("the filter is lost:") == 1
    assert "and 3d refuses it; the estimate is dead reckoning" in done.stderr
    # the scale check, whose pairs rest on the lost filter's attitude and biases, stands down:
    # it blamed the right baseline, "0.669 ± 0.043 times as far" (a probe)
    assert "is the stereo baseline right" not in done.stderr
    assert "times as far as the accelerometer" not in done.stderr
    default = _run(euroc_micro, tmp_path / "clone", "3d", 15)
    assert default["recovery"]["lost"] == [] and default["ate_rmse_m"] < 1.0
