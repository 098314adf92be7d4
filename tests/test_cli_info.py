"""``svains info`` on the real micro EuRoC set, KITTI, and a bad path (typer CliRunner)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from svains.cli.main import app

runner = CliRunner()


def _row(out: str, label: str) -> list[str]:
    line = next(ln for ln in out.splitlines() if ln.startswith(f"│ {label} "))
    return [c.strip() for c in line.strip("│").split("│")]


def test_info_euroc_micro(euroc_micro: Path, tmp_path: Path) -> None:
    res = runner.invoke(app, ["info", str(euroc_micro), "--json", str(tmp_path / "i.json")],
                        env={"COLUMNS": "140"})  # fmt: skip
    assert res.exit_code == 0, res.output
    out = res.output
    assert _row(out, "cam0 (left)")[:2] == ["cam0 (left)", "95"]
    assert _row(out, "cam1 (right)")[:2] == ["cam1 (right)", "95"]
    imu = _row(out, "imu0")
    assert imu[1] == "29120" and imu[2] == "200.00" and imu[4] == "145.595"
    gt = _row(out, "ground truth")
    assert gt[1] == "2895" and gt[2] == "20.00"
    assert "4 image(s) listed without a file, skipped (cam1: 4)" in out
    assert re.search(r"stereo baseline \(from T_BS of cam0/cam1\): 0\.110\d m", out)
    assert "fu=458.654 fv=457.296 cu=367.215 cv=248.375" in out
    summary = json.loads((tmp_path / "i.json").read_text())
    assert summary["missing_images"] == {"cam1": 4}
    assert summary["unreadable_images"] == {}
    assert summary["stereo_pairs"] == {"pairs": 95, "cam0_unpaired": 0, "cam1_unpaired": 0}
    assert summary["streams"]["imu"]["span_s"] == pytest.approx(145.595, abs=1e-3)
    assert summary["streams"]["groundtruth"]["rate_hz"] == pytest.approx(20.0, rel=1e-3)


def test_info_kitti(kitti_a: Path) -> None:
    res = runner.invoke(app, ["info", str(kitti_a)], env={"COLUMNS": "140"})
    assert res.exit_code == 0, res.output
    assert _row(res.output, "cam0 (left)")[1] == "51"
    assert "stereo baseline (from T_BS of cam0/cam1): 0.5372 m" in res.output
    assert "Missing files: none" in res.output


def test_info_shows_how_far_kitti_raw_sits_from_the_unit_and_frame_checks(
    kitti_raw: Path, tmp_path: Path
) -> None:
    res = runner.invoke(app, ["info", str(kitti_raw), "--json", str(tmp_path / "i.json")],
                        env={"COLUMNS": "200"})  # fmt: skip
    assert res.exit_code == 0, res.output
    assert ("imu0 accelerometer: median magnitude 9.823 m/s² against gravity 9.809"
            in res.output)  # fmt: skip
    assert ("GPS course against the gyro: cosine 0.99 over 8 turns (77° by the gyro), the "
            "course turning 1.05 times as far" in res.output)  # fmt: skip
    summary = json.loads((tmp_path / "i.json").read_text())
    gps = summary["calibration"]["gps"]
    assert gps["position_noise_std"] == 0.35 and gps["position_correlation_s"] == 0.0
    checks = summary["checks"]
    assert checks["gps_course_vs_gyro"]["turns"] == 8
    assert checks["gps_course_vs_gyro"]["course_per_gyro_turn"] == pytest.approx(1.047, abs=1e-3)


def test_info_lists_images_that_cannot_be_decoded(tmp_path: Path) -> None:
    """A PNG cut short, an empty file and a text file named .png (found by a user's probe:
    info said nothing, run dropped them one warning at a time): counted per camera from the
    files' first and last bytes, the first named with its reason; whole images are not."""
    from test_datasets_roundtrip import write_full

    root = tmp_path / "ds"
    write_full(root)
    left = sorted((root / "mav0" / "cam0" / "data").glob("*.png"))
    right = sorted((root / "mav0" / "cam1" / "data").glob("*.png"))
    left[1].write_bytes(left[1].read_bytes()[:-20])
    left[2].write_bytes(b"")
    right[0].write_text("not an image")
    # cam1 stopped two frames early: its last two rows gone (a user's probe: info was silent)
    csv1 = root / "mav0" / "cam1" / "data.csv"
    csv1.write_text("\n".join(csv1.read_text().rstrip("\n").split("\n")[:-2]) + "\n")
    res = runner.invoke(app, ["info", str(root), "--json", str(tmp_path / "i.json")],
                        env={"COLUMNS": "400"})  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (f"Unreadable files: 3 image(s) that cannot be decoded, dropped by run (cam0: 2, cam1: "
            f"1; first {left[1]}: no PNG end chunk (cut short?))") in res.output
    assert "Stereo pairs: 2; without a partner: cam0 2, cam1 0 frame(s)" in res.output
    assert json.loads((tmp_path / "i.json").read_text())["stereo_pairs"] == {
        "pairs": 2, "cam0_unpaired": 2, "cam1_unpaired": 0}
    unreadable = json.loads((tmp_path / "i.json").read_text())["unreadable_images"]
    assert unreadable["cam1"] == {"count": 1, "first": str(right[0]),
                                  "reason": "not a PNG (no PNG signature)"}  # fmt: skip


def test_info_missing_folder(tmp_path: Path) -> None:
    res = runner.invoke(app, ["info", str(tmp_path / "nope")])
    assert res.exit_code == 1
    assert "data set folder not found" in res.output


def test_info_help() -> None:
    res = runner.invoke(app, ["info", "--help"])
    assert res.exit_code == 0
    assert "dataset" in res.output.lower() and "--json" in res.output


@pytest.mark.parametrize("module", ["svains", "svains.cli.main"])
def test_the_command_runs_as_a_module(module: str, tmp_path: Path) -> None:
    """``python -m svains`` said "no module named svains.__main__", and ``-m svains.cli.main``
    did nothing and exited 0 (a user's probe)."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", module, "run", str(tmp_path / "none")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 1
    assert res.stderr.strip() == f"error: data set folder not found: {tmp_path / 'none'}"


def test_info_reads_a_camchain_and_shows_the_mount_and_the_refusal(
    euroc_micro: Path, tmp_path: Path
) -> None:
    """``info --calib`` shows the cameras as ``run --calib`` reads them: where each looks on
    the body, cam1's place in cam0's axes; a rig ``run`` refuses (cam1 left of cam0) is said
    (it was hidden: info printed a baseline and exit 0, a user's probe)."""
    from _kalibr_files import write_euroc_kalibr
    from svains.datasets import load_dataset
    from svains.datasets.kalibr import write_camchain

    ds = load_dataset(euroc_micro)
    chain, _ = write_euroc_kalibr(ds, tmp_path / "k")
    res = runner.invoke(app, ["info", str(euroc_micro), "--calib", str(chain)],
                        env={"COLUMNS": "200"})  # fmt: skip
    assert res.exit_code == 0, res.output
    assert re.search(r"cam1 at \[\+0\.110, [-+]0\.000, \+0\.001\] m in cam0's axes", res.output)
    assert re.search(r"on the body: at \[-0\.022, -0\.065, \+0\.010\] m, looking along", res.output)
    assert "timeshift_cam_imu 0 ms" in res.output
    swapped = write_camchain(tmp_path / "swapped.yaml", [ds.cam1, ds.cam0],
                             T_B_I=ds.imu_calib.T_B_S)  # fmt: skip
    res = runner.invoke(app, ["info", str(euroc_micro), "--calib", str(swapped)],
                        env={"COLUMNS": "200"})  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "stereo pair: refused: stereo rectification: cam1 must be right of cam0" in res.output


def test_a_stream_missing_samples_shows_its_mean_rate_beside_the_median(kitti_raw: Path) -> None:
    """KITTI raw's IMU: 25 Hz by its median step, 16 Hz on average, 100 Hz declared: three
    numbers, none labelled (a probe)."""
    res = runner.invoke(app, ["info", str(kitti_raw)], env={"COLUMNS": "160"})
    assert res.exit_code == 0, res.output
    assert _row(res.output, "imu0")[2] == "25.00 (15.96 mean)"
    assert "rate [Hz] (median step)" in res.output
    assert "imu0: 100 Hz declared" in res.output
