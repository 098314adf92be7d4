"""The KITTI raw figures the results page shows (docs/results/kitti.md), under test (issue 26):
``3d`` from images GPS-denied from the reference start, and with an in-flight GPS start and two
10 s GPS outages. Each limit is the measured figure with a stated margin."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.kalibr import write_camchain

pytestmark = [pytest.mark.realdata]


def _run(kitti_raw: Path, out: Path, *args: str) -> dict[str, Any]:
    svains = Path(sys.executable).with_name("svains")
    cmd = [str(svains), "run", str(kitti_raw), "--method", "3d", "--images", "--no-mag",
           "--out", str(out), *args]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return dict(json.loads((out / "report.json").read_text(encoding="utf-8")))


def test_gps_denied_3d_ends_where_the_results_page_says(kitti_raw: Path, tmp_path: Path) -> None:
    # svains run ../shared/data/kitti_raw_0926_41s --method 3d --images --init groundtruth
    #   --no-gps --no-mag: measured 2026-12-02 final error 1.359 % of the path, ATE 0.296 m,
    #   NEES 79.2 (the target 0.8 % is the known limitation). The page's figure to 0.01 %.
    r = _run(kitti_raw, tmp_path / "gd", "--init", "groundtruth", "--no-gps")
    assert r["final_error_pct"] == pytest.approx(1.359, abs=0.01)
    assert r["ate_rmse_m"] < 0.296 * 1.05
    assert r["nees_mean"] < 79.2 * 1.1
    # the ATE's se3 fit tilts the gravity-aligned run (measured 2026-12-07: 6.75°), said in the
    # report and the run table (a probe: `svains evaluate` said so, `svains run` did not)
    assert r["alignment"] == "se3" and r["ate_fit_tilt_deg"] == pytest.approx(6.75, abs=0.5)
    # the baseline's check by the accelerometer: measured 1.026 ± 0.021, not warned
    scale = r["vision"]["scale_check"]
    assert scale["factor"] == pytest.approx(1.0, abs=0.05) and not scale["warned"]


def test_gps_outages_stay_within_the_measured_largest_errors(
    kitti_raw: Path, tmp_path: Path
) -> None:
    # ... --init gps --no-mag --gps-outage 10:10 --gps-outage 25:10: measured 2026-12-02 largest
    # error 0.660 / 0.511 m in the two outages, NEES 11.3 (limits 1.1x: one seeded front end).
    r = _run(kitti_raw, tmp_path / "out", "--init", "gps", "--gps-outage", "10:10",
             "--gps-outage", "25:10")  # fmt: skip
    first, second = r["outage_max_error_m"]
    assert first == pytest.approx(0.660, abs=0.066) and second == pytest.approx(0.511, abs=0.051)
    assert r["nees_mean"] < 11.3 * 1.1
    # the baseline's check by the GPS speeds: measured 0.9986 ± 0.001 without the outages
    scale = r["vision"]["scale_check"]
    assert scale["gps_factor"] == pytest.approx(1.0, abs=0.005) and not scale["warned_gps"]


def test_the_camera_rotation_considered_makes_the_outage_run_honest(
    kitti_raw: Path, tmp_path: Path
) -> None:
    # the outage command with --set vision.consider_extrinsics_std_deg=0.5: measured
    # 2026-12-07 NEES 8.3 (11.3 without), every position inside 3σ, outages 0.59 / 0.64 m
    # (0.66 / 0.51 without)
    r = _run(kitti_raw, tmp_path / "con", "--init", "gps", "--gps-outage", "10:10",
             "--gps-outage", "25:10", "--set", "vision.consider_extrinsics_std_deg=0.5")
    assert r["vision"]["extrinsic_rotation_considered_std_deg"] == pytest.approx(0.5)
    assert r["nees_mean"] < 9.0 and r["position_within_3sigma"] == 1.0
    first, second = r["outage_max_error_m"]
    assert first == pytest.approx(0.59, abs=0.06) and second == pytest.approx(0.64, abs=0.064)
    # smoothing such a run is refused: the backward pass over a Schmidt run can end worse than
    # the filter (a review)
    svains = Path(sys.executable).with_name("svains")
    res = subprocess.run([str(svains), "run", str(kitti_raw), "--method", "3d", "--smooth",
                          "--set", "vision.consider_extrinsics_std_deg=0.5", "--out",
                          str(tmp_path / "refused")], capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 2
    assert "does not handle vision.consider_extrinsics_std_deg" in res.stderr


def test_a_stereo_baseline_10_percent_long_is_warned_by_the_gps(
    kitti_raw: Path, tmp_path: Path
) -> None:
    # cam1's T_BS moved along the baseline by 10 %: KITTI raw 3d with GPS ends at ATE 1.7 m
    # (0.22 m right) under warnings of a bias step; the GPS speeds measure 1.098 ± 0.001.
    ds = load_dataset(kitti_raw)
    assert ds.cam0 is not None and ds.cam1 is not None and ds.imu_calib is not None
    T_B_C0 = np.asarray(ds.cam0.T_B_C, float)
    T_C0_C1 = np.linalg.inv(T_B_C0) @ np.asarray(ds.cam1.T_B_C, float)
    T_C0_C1[:3, 3] *= 1.1
    chain = write_camchain(tmp_path / "camchain.yaml",
                           (ds.cam0, replace(ds.cam1, T_B_C=T_B_C0 @ T_C0_C1)),
                           ds.imu_calib.T_B_S, ds.cam0.timeshift_cam_imu_s)  # fmt: skip
    svains = Path(sys.executable).with_name("svains")
    out = tmp_path / "run"
    p = subprocess.run([str(svains), "run", str(kitti_raw), "--method", "3d", "--images",
                        "--no-mag", "--init", "gps", "--duration", "20", "--calib", str(chain),
                        "--out", str(out)], capture_output=True, text=True, check=True)  # fmt: skip
    said = [line for line in p.stderr.splitlines() if "stereo baseline" in line]
    assert len(said) == 1 and "times as far as the GPS says" in said[0]
    scale = json.loads((out / "report.json").read_text(encoding="utf-8"))["vision"]["scale_check"]
    assert scale["warned_gps"] and scale["gps_factor"] == pytest.approx(1.1, abs=0.01)
