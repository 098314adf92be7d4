"""``svains run`` with Kalibr files (``--calib``/``--imu-calib``, ``replay.calib`` in the
configuration) on a ROS bag and on the folder, ``--rerun``, and the per-update logs a run writes
(``updates.csv``, ``tracks.csv``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from _kalibr_files import write_euroc_kalibr
from svains.cli.main import app
from svains.datasets import load_dataset
from svains.datasets.rosbag_writer import write_bag
from svains.errors import DatasetError
from svains.evaluation.run_record import read_run

runner = CliRunner()
# 3d from images, static start: the bag's 1.6 s cover the 0.5 s start and 1 s of vision.
_RUN_3D = ["--method", "3d", "--images", "--init", "static", "--set", "init.static_s=0.5",
           "--rotation", "imu", "--duration", "1.0"]  # fmt: skip


def _run(args: list[str]) -> str:
    res = runner.invoke(app, ["run", *args])
    assert res.exit_code == 0, res.output
    return res.output


@pytest.fixture(scope="module")
def bag_and_kalibr(euroc_micro: Path, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    ds = load_dataset(euroc_micro)
    root = tmp_path_factory.mktemp("bag")
    bag = write_bag(ds, root / "micro.bag", "ros1", t_end_ns=int(ds.left.t_ns[0]) + 1_600_000_000)
    return bag, *write_euroc_kalibr(ds, root / "kalibr")


def test_bag_with_kalibr_runs_like_the_folder_and_records(
    euroc_micro: Path, bag_and_kalibr, tmp_path: Path  # type: ignore[no-untyped-def]
) -> None:
    bag, chain, imu = bag_and_kalibr
    kal = ["--calib", str(chain), "--imu-calib", str(imu)]
    rrd = tmp_path / "bag.rrd"
    rerun = ["--rerun", str(rrd)] if _has_rerun() else []
    _run([str(bag), "--out", str(tmp_path / "bag"), *_RUN_3D, *kal, *rerun])
    _run([str(euroc_micro), "--out", str(tmp_path / "folder"), *_RUN_3D, *kal])
    on_bag = (tmp_path / "bag" / "trajectory.tum").read_text()
    assert on_bag == (tmp_path / "folder" / "trajectory.tum").read_text()
    assert len(on_bag.splitlines()) >= 10
    rep = json.loads((tmp_path / "bag" / "report.json").read_text())
    assert rep["vision"]["frames_fused"] >= 8
    # The Kalibr paths live in the effective configuration, absolute, and reproduce the run.
    cfg = yaml.safe_load((tmp_path / "bag" / "config.yaml").read_text())
    assert cfg["replay"]["calib"] == str(chain.resolve())
    assert cfg["replay"]["imu_calib"] == str(imu.resolve())
    _run([str(bag), "--out", str(tmp_path / "again"), "--config",
          str(tmp_path / "bag" / "config.yaml")])  # fmt: skip
    assert (tmp_path / "again" / "trajectory.tum").read_text() == on_bag
    if rerun:
        from rerun.chunk import RrdReader

        paths = set(RrdReader(rrd).store().schema().entity_paths())
        assert paths >= {"/world/estimate", "/camera/left", "/camera/left/inliers",
                         "/camera/left/outliers", "/camera/left/tracks", "/nis/3d"}  # fmt: skip


def _has_rerun() -> bool:
    try:
        import rerun  # noqa: F401
    except ImportError:
        return False
    return True


def test_a_3d_image_run_writes_updates_and_tracks(euroc_micro: Path, tmp_path: Path) -> None:
    _run([str(euroc_micro), "--out", str(tmp_path), "--method", "3d", "--images", "--duration",
          "2"])  # fmt: skip
    head = {n: (tmp_path / n).read_text().splitlines()[0] for n in ("updates.csv", "tracks.csv")}
    assert head == {"updates.csv": "t_ns,sensor,nis,dof,accepted",
                    "tracks.csv": "t_ns,track_id,u_px,v_px,inlier"}  # fmt: skip
    rec = read_run(tmp_path)
    assert rec.updates is not None and rec.tracks is not None
    counts = json.loads((tmp_path / "report.json").read_text())["measurements"]
    sensors = rec.updates["sensor"]
    # One row per update, counted as report.json counts them.
    assert set(sensors.tolist()) == set(counts)
    for name, c in counts.items():
        acc = rec.updates["accepted"][sensors == name]
        assert (int(acc.sum()), int((acc == 0).sum())) == (c["fused"], c["rejected"])
    assert (rec.updates["dof"][sensors == "3d"] % 4 == 0).all()  # 4 pixels per feature
    assert np.isfinite(rec.updates["nis"]).all()
    trk = rec.tracks
    ds = load_dataset(euroc_micro)
    assert np.isin(trk["t_ns"], ds.left.t_ns).all()  # stamped with stereo frames
    assert set(np.unique(trk["inlier"]).tolist()) == {0.0, 1.0}
    # Raw left-image pixels: inside EuRoC's 752x480 images (rectified ones would leave them
    # near the borders, where the rectifying rotation and the distortion move pixels most).
    ok = np.isfinite(trk["u_px"])
    assert ok.mean() > 0.99
    assert (trk["u_px"][ok] > -1).all() and (trk["u_px"][ok] < 753).all()
    assert (trk["v_px"][ok] > -1).all() and (trk["v_px"][ok] < 481).all()
    # read only when asked (an hour's tracks.csv, 770 MB, made `svains plot` take 103 s and
    # 7.4 GB for figures that never use it), by numpy: the same columns as the plain reader
    from svains.evaluation.run_record import _csv_columns

    plain = _csv_columns(tmp_path / "tracks.csv")
    assert list(trk) == list(plain) and all(np.array_equal(trk[k], plain[k]) for k in trk)
    (tmp_path / "tracks.csv").write_text("t_ns,track_id,u_px,v_px,inlier\n1,2,3\n")
    lazy = read_run(tmp_path)
    with pytest.raises(DatasetError, match=r"tracks\.csv:2: expected 5 fields"):
        _ = lazy.tracks


def test_a_run_without_vision_removes_stale_logs(euroc_micro: Path, tmp_path: Path) -> None:
    _run([str(euroc_micro), "--out", str(tmp_path), "--method", "3d", "--images", "--duration",
          "1"])  # fmt: skip
    assert (tmp_path / "tracks.csv").is_file()
    _run([str(euroc_micro), "--out", str(tmp_path), "--method", "ins", "--duration", "1",
          "--force"])  # fmt: skip
    assert not (tmp_path / "tracks.csv").exists()  # no vision: an older run's tracks would lie


def test_a_missing_kalibr_file_is_refused(euroc_micro: Path, tmp_path: Path) -> None:
    res = runner.invoke(app, ["run", str(euroc_micro), "--out", str(tmp_path / "o"),
                              "--calib", str(tmp_path / "nope.yaml")])  # fmt: skip
    assert res.exit_code != 0
    assert "nope.yaml" in res.output


def test_compare_takes_the_kalibr_files_for_a_bag(bag_and_kalibr, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    bag, chain, imu = bag_and_kalibr
    args = ["compare", str(bag), "--out", str(tmp_path), "--methods", "3d", "--images",
            "--no-figures", "--duration", "1", "--rotation", "imu"]  # fmt: skip
    res = runner.invoke(app, args)
    # compare writes what it could and exits 1 naming the failed method (issue 23)
    assert res.exit_code == 1, res.output
    assert res.stderr.strip().splitlines()[-1] == (
        "error: 1 of 1 method(s) failed: 3d (method 3d needs the cam0 and cam1 calibrations "
        "(the rig's cam0 and cam1); without cameras use method ins)"
    )
    assert (tmp_path / "compare.md").is_file()
    assert not (tmp_path / "3d" / "report.json").exists()  # a bag has no camera calibration
    res = runner.invoke(app, [*args, "--force", "--calib", str(chain), "--imu-calib", str(imu)])
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "compare.json").read_text())["3d"]
    assert rep["vision"]["frames_fused"] >= 8
    assert all((tmp_path / "3d" / n).is_file() for n in ("updates.csv", "tracks.csv"))
