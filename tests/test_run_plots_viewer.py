"""``svains plot`` and ``svains view`` on a short real run (EuRoC micro, ``3d`` from images):
the PNGs hold the expected panels and the ``.rrd`` opens with rerun's reader with the expected
entities, including the per-update logs (updates.csv, tracks.csv) when a run has them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from svains.cli.main import app
from svains.datasets import load_dataset
from svains.errors import DatasetError
from svains.evaluation.plots import plot_run
from svains.evaluation.run import run_method
from svains.evaluation.run_record import read_run, run_errors
from svains.navigation.options import InitOptions, RunOptions, VisionOptions

runner = CliRunner()


@pytest.fixture(scope="module")
def run_dir(euroc_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    ds = load_dataset(euroc_micro)
    opts = RunOptions(
        init=InitOptions(mode="static", static_s=0.5), duration_s=1.0,
        vision=VisionOptions(source="images", rotation="imu"),
    )  # fmt: skip
    out = tmp_path_factory.mktemp("run")
    run_method(ds, "3d", opts, out_dir=out)
    return out


def _with_logs(run_dir: Path, tmp_path: Path, euroc_micro: Path) -> Path:
    """A copy of the run with hand-made updates.csv and tracks.csv in the documented layout."""
    d = tmp_path / "run"
    d.mkdir()
    for name in ("states.csv", "report.json", "trajectory.tum"):
        (d / name).write_text((run_dir / name).read_text())
    t = load_dataset(euroc_micro).left.t_ns[10:13].tolist()
    (d / "updates.csv").write_text(
        "t_ns,sensor,nis,dof,accepted\n"
        f"{t[0]},3d,200.5,240,1\n{t[1]},3d,900.0,240,0\n{t[2]},gps,4.0,6,1\n"
    )
    rows = [f"{ti},{k},{100 + 5 * j + k},{200 + k},{int(k != 2)}" for j, ti in enumerate(t)
            for k in range(3)]  # fmt: skip
    (d / "tracks.csv").write_text("t_ns,track_id,u_px,v_px,inlier\n" + "\n".join(rows) + "\n")
    return d


def test_plot_writes_errors_nees_and_measurement_panels(
    run_dir: Path, euroc_micro: Path, tmp_path: Path
) -> None:
    d = _with_logs(run_dir, tmp_path, euroc_micro)
    files = plot_run(d, load_dataset(euroc_micro), d / "p")
    panels = {f.path.name: f.panels for f in files}
    assert set(panels) == {"errors.png", "nees.png", "measurements.png"}
    assert panels["errors.png"][0] == "position x [m]" and len(panels["errors.png"]) == 9
    assert panels["errors.png"][8] == "attitude z [deg]"
    assert panels["nees.png"][0].startswith("NEES over time, diagonal covariance (mean ")
    assert panels["measurements.png"] == ("3d: 1 fused, 1 rejected", "gps: 1 fused, 0 rejected")
    for name in panels:
        head = (d / "p" / name).read_bytes()[:8]
        assert head == b"\x89PNG\r\n\x1a\n", name


def test_plot_uses_the_updates_log_the_run_wrote(run_dir: Path, tmp_path: Path) -> None:
    counts = read_run(run_dir).report["measurements"]
    files = plot_run(run_dir, None, tmp_path)
    # One panel per sensor in the log: the vision method and the start's zero-velocity updates.
    assert files[0].panels == tuple(f"{s}: {c['fused']} fused, {c['rejected']} rejected"
                                    for s, c in sorted(counts.items()))  # fmt: skip
    assert set(counts) == {"3d", "zupt"}


def test_plot_without_updates_log_shows_report_totals(run_dir: Path, tmp_path: Path) -> None:
    d = tmp_path / "run"
    d.mkdir()
    for name in ("states.csv", "report.json"):  # an older run's folder: no updates.csv
        (d / name).write_text((run_dir / name).read_text())
    files = plot_run(d, None, tmp_path)
    assert [f.path.name for f in files] == ["measurements.png"]
    assert files[0].panels[0].startswith("fused/rejected totals (report.json; no updates.csv")
    res = runner.invoke(app, ["plot", str(d), "--out", str(tmp_path / "cli")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "cli" / "measurements.png").is_file()
    assert "no --dataset: errors.png and nees.png need its ground truth" in res.output


def test_run_errors_reproduce_the_reported_position_rmse(run_dir: Path, euroc_micro: Path) -> None:
    rec = read_run(run_dir)
    err = run_errors(rec, load_dataset(euroc_micro).groundtruth)
    rmse = np.sqrt(np.mean(np.sum(err.e[:, 0:3] ** 2, axis=1)))
    # states.csv rounds to 9 significant digits; report.json used the in-memory states.
    assert rmse == pytest.approx(rec.report["position_rmse_m"], rel=1e-5)
    assert err.alignment == rec.report["errors_alignment"] == "posyaw"


def test_view_saves_a_recording_with_the_expected_entities(
    run_dir: Path, euroc_micro: Path, tmp_path: Path
) -> None:
    pytest.importorskip("rerun")  # the viz extra; make test installs it
    from rerun.chunk import RrdReader

    d = _with_logs(run_dir, tmp_path, euroc_micro)
    rrd = tmp_path / "run.rrd"
    res = runner.invoke(app, ["view", str(d), "--dataset", str(euroc_micro), "--out", str(rrd),
                              "--image-stride", "4"])  # fmt: skip
    assert res.exit_code == 0, res.output
    schema = RrdReader(rrd).store().schema()
    paths = set(schema.entity_paths())
    assert paths >= {
        "/world/groundtruth", "/world/estimate", "/world/body", "/world/body_3sigma",
        "/errors/position_m", "/nees", "/camera/left", "/camera/left/inliers",
        "/camera/left/outliers", "/camera/left/tracks", "/nis/3d", "/nis/gps",
    }  # fmt: skip
    assert any("Ellipsoids3D" in c for c in schema.column_names())


def test_view_and_plot_refuse_a_folder_that_is_not_a_run(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"not a run folder \(missing states\.csv"):
        read_run(tmp_path)
    res = runner.invoke(app, ["view", str(tmp_path)])
    assert res.exit_code == 2 and "--out x.rrd, --spawn, or both" in res.output


def test_view_and_plot_never_replace_a_file_without_force(run_dir: Path, tmp_path: Path) -> None:
    # Checked before any work: a user's file of that name is left as it was.
    mine = tmp_path / "mine.rrd"
    mine.write_text("mine\n")
    res = runner.invoke(app, ["view", str(run_dir), "--out", str(mine)])
    assert res.exit_code == 2 and "exists; use --force to replace it" in res.stderr
    assert mine.read_text() == "mine\n"
    out = tmp_path / "figs"
    out.mkdir()
    (out / "measurements.png").write_text("mine\n")
    res = runner.invoke(app, ["plot", str(run_dir), "--out", str(out)])
    assert res.exit_code == 2 and "measurements.png exists; use --force" in res.stderr
    assert (out / "measurements.png").read_text() == "mine\n"
    res = runner.invoke(app, ["plot", str(run_dir), "--out", str(out), "--force"])
    assert res.exit_code == 0, res.output
    assert (out / "measurements.png").read_bytes()[:4] == b"\x89PNG"


def test_plot_with_a_data_set_without_ground_truth_or_of_another_name_still_draws(
    run_dir: Path, euroc_micro: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A user's probe: --dataset without ground truth wrote nothing (exit 1); another data set
    than the run's was plotted against without a word; a report.json given for the folder was
    refused as an '--out' problem."""
    from dataclasses import replace

    ds = load_dataset(euroc_micro)
    with caplog.at_level("WARNING", logger="svains.evaluation.plots"):
        files = plot_run(run_dir, replace(ds, groundtruth=None), tmp_path / "a")
        assert [f.path.name for f in files] == ["measurements.png"]
        assert "no ground truth, so no error or NEES plots" in caplog.text
        assert "was made on the data set" not in caplog.text
        plot_run(run_dir, replace(ds, name="other"), tmp_path / "b")
    assert (f"{run_dir} was made on the data set 'euroc_v101_micro', and {ds.root} is 'other'"
            in caplog.text)  # fmt: skip
    res = runner.invoke(app, ["plot", str(run_dir / "report.json"), "--out", str(tmp_path / "c")])
    assert res.exit_code == 2
    assert f"report.json is a file: give the run's folder ({run_dir})" in res.stderr


def test_an_empty_or_header_only_tracks_file_is_read_as_the_plain_reader_reads_it(
    run_dir: Path, tmp_path: Path, euroc_micro: Path
) -> None:
    """A review's case: numpy read an empty ``tracks.csv`` (a run cut short) as ``{'': []}``,
    which the viewer failed on later, and warned twice on a header alone."""
    import warnings

    d = _with_logs(run_dir, tmp_path, euroc_micro)
    (d / "tracks.csv").write_text("")
    with pytest.raises(DatasetError, match=r"tracks\.csv: empty file"):
        _ = read_run(d).tracks
    (d / "tracks.csv").write_text("t_ns,track_id,u_px,v_px,inlier\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tracks = read_run(d).tracks
    assert tracks is not None and list(tracks) == ["t_ns", "track_id", "u_px", "v_px", "inlier"]
    assert all(c.size == 0 for c in tracks.values()) and tracks["t_ns"].dtype == np.int64


def test_run_errors_follow_the_reports_start_position_frame(tmp_path: Path) -> None:
    """A local run whose magnetometer fixed the heading is read from its first position
    (``start_position``); the plots read it unaligned, 22 m off (a review)."""
    from svains.evaluation.run import run_method
    from svains.navigation.options import RunOptions
    from svains.sim import SimConfig, simulate
    from svains.sim.config import ImuConfig

    cfg = SimConfig(duration_s=8.0, seed=1, imu=ImuConfig.preset("adis16448"))
    cfg.trajectory.stops = [[0.0, 4.0]]
    cfg.camera.render_images = False
    ds = load_dataset(simulate(cfg, tmp_path / "ds"))
    out = tmp_path / "run"
    res = run_method(ds, "ins", RunOptions(use_gps=False, use_sonar=False), out_dir=out)
    assert res.report["errors_alignment"] == "start_position"
    err = run_errors(read_run(out), ds.groundtruth)
    assert err.alignment == "start_position"
    rmse = np.sqrt(np.mean(np.sum(err.e[:, 0:3] ** 2, axis=1)))
    assert rmse == pytest.approx(res.report["position_rmse_m"], rel=1e-5)


def _flight_and_kalibr_imu(tmp_path: Path) -> tuple[Path, Path]:
    """A 3 s simulated flight (its root) and a Kalibr imu.yaml of its IMU beside it."""
    from dataclasses import replace

    from svains.datasets.kalibr import write_kalibr_imu
    from svains.sim import SimConfig, simulate

    cfg = SimConfig(duration_s=3.0, seed=1)
    cfg.camera.render_images = False
    root = simulate(cfg, tmp_path / "sim")
    ds = load_dataset(root)
    assert ds.imu_calib is not None
    # the simulator's IMU has no random walk by default; Kalibr's file wants one
    calib = replace(ds.imu_calib, gyro_random_walk=1e-5, accel_random_walk=1e-4)
    return root, write_kalibr_imu(tmp_path / "imu.yaml", calib)


def test_plot_reads_the_data_set_with_the_kalibr_files_of_the_run(tmp_path: Path) -> None:
    """A folder whose IMU is calibrated by a Kalibr imu.yaml alone (docs/own-sensor.md): plot
    read it without the file the run was given and stopped on the missing sensor.yaml, naming
    an --imu-calib it does not take (a user's probe); it now reads the run's config.yaml."""
    root, imu_yaml = _flight_and_kalibr_imu(tmp_path)
    (root / "mav0/imu0/sensor.yaml").unlink()
    run = tmp_path / "run"
    res = runner.invoke(app, ["run", str(root), "--method", "ins", "--init", "groundtruth",
                              "--imu-calib", str(imu_yaml), "--out", str(run)])  # fmt: skip
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["plot", str(run), "--dataset", str(root), "--out",
                              str(tmp_path / "figs")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (tmp_path / "figs" / "errors.png").read_bytes()[:4] == b"\x89PNG"
    (run / "config.yaml").unlink()  # without it: the plain reading
    res = runner.invoke(app, ["plot", str(run), "--dataset", str(root), "--out",
                              str(tmp_path / "figs2")])  # fmt: skip
    assert res.exit_code == 1 and "imu0/sensor.yaml" in res.stderr


def test_kalibr_files_of_a_run_are_recorded_absolute_and_missing_ones_are_warned(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A review: a relative `--set replay.imu_calib=imu.yaml` was recorded as written, and a
    file moved since the run stopped `svains plot` on a data set with its own calibration."""
    import yaml

    root, _ = _flight_and_kalibr_imu(tmp_path)
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "run"
    res = runner.invoke(app, ["run", str(root), "--method", "ins", "--init", "groundtruth",
                              "--set", "replay.imu_calib=imu.yaml", "--out", str(run)])  # fmt: skip
    assert res.exit_code == 0, res.output
    recorded = yaml.safe_load((run / "config.yaml").read_text())["replay"]["imu_calib"]
    assert recorded == str((tmp_path / "imu.yaml").resolve())
    (tmp_path / "imu.yaml").rename(tmp_path / "moved.yaml")
    with caplog.at_level("WARNING", logger="svains.evaluation.run_record"):
        res = runner.invoke(app, ["plot", str(run), "--dataset", str(root), "--out",
                                  str(tmp_path / "figs")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "names replay.imu_calib" in caplog.text and "which is not found" in caplog.text
