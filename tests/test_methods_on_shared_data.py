"""Every method on every shared data set: it runs, or it refuses in one documented line
(issue 23: ``vo`` on stereo-only KITTI odometry had regressed to "no IMU stream")."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from svains.cli.main import app

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

METHODS = ("ins", "vo", "lc", "tc", "3d")
# What each data set needs beyond the defaults: KITTI raw starts moving (no static start).
EXTRA = {
    "euroc_v101_micro": ["--duration", "3"],
    "kitti_raw_0926_41s": ["--init", "groundtruth", "--duration", "4"],
    "kitti_stereo_a": [],
}
NO_IMU = "no IMU stream (method {m} needs one; vo and svains frontend run on stereo alone)"


@pytest.mark.parametrize("data", sorted(EXTRA))
@pytest.mark.parametrize("method", METHODS)
def test_method_runs_or_refuses_in_one_line(data: str, method: str, tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[1].parent / "shared" / "data" / data
    if not root.is_dir():
        pytest.fail(f"real data missing: {root} (CI provides ../shared)")
    args = ["run", str(root), "--method", method, "--out", str(tmp_path / "run"), *EXTRA[data]]
    res = CliRunner().invoke(app, args)
    if data == "kitti_stereo_a" and method != "vo":
        assert res.exit_code == 1, res.output
        err = res.stderr.strip().splitlines()
        assert err == [f"error: kitti_stereo_a: {NO_IMU.format(m=method)}"]
        return
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "run" / "report.json").read_text(encoding="utf-8"))
    assert report["method"] == method
    assert report["ate_rmse_m"] is not None and report["ate_rmse_m"] < 5.0
    # the line naming the files names those written (vo's named a covariance it has not)
    wrote = next(ln for ln in res.stdout.splitlines() if ln.startswith("wrote "))
    named = [n.strip() for n in wrote.split("/")[-1].split(",")]
    assert sorted(named) == sorted(p.name for p in (tmp_path / "run").iterdir()), wrote


def test_compare_with_a_failing_method_writes_the_rest_and_exits_1(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_stereo_a"
    if not root.is_dir():
        pytest.fail(f"real data missing: {root} (CI provides ../shared)")
    out = tmp_path / "cmp"
    res = CliRunner().invoke(app, ["compare", str(root), "--out", str(out), "--methods",
                                   "ins,vo", "--no-figures"])  # fmt: skip
    assert res.exit_code == 1, res.output
    err = [ln for ln in res.stderr.splitlines() if ln.startswith("error: ")]
    why = f"kitti_stereo_a: {NO_IMU.format(m='ins')}"
    assert err == [f"error: 1 of 2 method(s) failed: ins ({why})"]
    reports = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    assert "error" in reports["ins"] and reports["vo"]["ate_m"] < 1.0
