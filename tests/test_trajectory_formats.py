"""``svains evaluate`` inputs: the same trajectory as TUM, an EuRoC data.csv, KITTI poses and a
bag topic gives the same ATE; formats are detected from the files, ``--format`` overrides."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from svains.cli.main import app
from svains.datasets import load_dataset
from svains.datasets.rosbag_writer import write_bag
from svains.datasets.trajectory import ns_to_seconds_text, write_tum
from svains.datasets.trajectory_formats import detect_format, read_trajectory
from svains.datasets.types import Dataset
from svains.errors import DatasetError
from svains.geometry.rotation import quat_multiply, quat_to_rotmat, rotmat_to_quat, so3_exp

runner = CliRunner()


@pytest.fixture(scope="module")
def files(euroc_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The micro ground truth's first 300 poses moved rigidly with noise, in every format."""
    full = load_dataset(euroc_micro).groundtruth
    t, p0, q0 = full.t_ns[:300], full.p_W_B[:300], full.q_W_B_wxyz[:300]
    rng = np.random.default_rng(14)
    R = so3_exp([0.2, -0.1, 1.0])
    p = p0 @ R.T + [1.0, 2.0, -0.5] + rng.normal(scale=0.02, size=p0.shape)
    q = quat_multiply(rotmat_to_quat(R), q0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    d = tmp_path_factory.mktemp("formats")
    out = {"tum": write_tum(d / "est.tum", t, p, q)}
    a = np.concatenate([p, q], axis=1).tolist()
    rows = [f"{ti},{','.join(repr(v) for v in r)}" for ti, r in zip(t.tolist(), a, strict=True)]
    (d / "est.csv").write_text("#timestamp [ns],x,y,z,qw,qx,qy,qz\n" + "\n".join(rows) + "\n")
    out["euroc"] = d / "est.csv"
    (d / "kitti").mkdir()
    T = np.concatenate([quat_to_rotmat(q), p[:, :, None]], axis=2).reshape(-1, 12)
    np.savetxt(d / "kitti" / "poses.txt", T, fmt="%.17g")
    (d / "kitti" / "times.txt").write_text("\n".join(ns_to_seconds_text(ti) for ti in t) + "\n")
    out["kitti"] = d / "kitti" / "poses.txt"
    est = Dataset(root=d, name="est", groundtruth=type(full)(t, p, q, 0 * p, 0 * p, 0 * p))
    out["bag"] = write_bag(est, d / "est.bag", "ros1", topics={"gt": "/estimate"})
    # a run's states.csv: stamps, p, v, q (w first), then more columns
    head = ("t_ns,p_W_B_x,p_W_B_y,p_W_B_z,v_W_B_x,v_W_B_y,v_W_B_z,q_W_B_w,q_W_B_x,q_W_B_y,"
            "q_W_B_z,omega_B_x")
    srows = [f"{ti},{','.join(repr(v) for v in (*pi, 0.0, 0.0, 0.0, *qi, 0.5))}"
             for ti, pi, qi in zip(t.tolist(), p.tolist(), q.tolist(), strict=True)]
    (d / "states.csv").write_text(head + "\n" + "\n".join(srows) + "\n")
    out["states"] = d / "states.csv"
    out["ref"] = euroc_micro / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    return out


def test_every_format_reads_the_same_trajectory(files: dict[str, Path]) -> None:
    t, p, q = read_trajectory(files["tum"])
    for fmt in ("euroc", "kitti", "bag", "states"):
        assert detect_format(files[fmt]) == fmt
        t2, p2, q2 = read_trajectory(files[fmt])
        np.testing.assert_array_equal(t2, t)
        np.testing.assert_allclose(p2, p, atol=1e-12)
        np.testing.assert_allclose(np.abs(np.sum(q2 * q, axis=1)), 1.0, atol=1e-12)
    assert detect_format(files["tum"]) == "tum" and detect_format(files["ref"]) == "euroc"


def test_evaluate_gives_the_same_ate_for_every_format(
    files: dict[str, Path], tmp_path: Path
) -> None:
    ates = {}
    for fmt in ("tum", "euroc", "kitti", "bag", "states"):
        out = tmp_path / f"{fmt}.json"
        res = runner.invoke(
            app, ["evaluate", str(files[fmt]), str(files["ref"]), "--json", str(out)]
        )
        assert res.exit_code == 0, res.output
        ates[fmt] = json.loads(out.read_text())["ate"]
    assert ates["tum"]["n"] == 300
    for fmt in ("euroc", "kitti", "bag"):
        assert ates[fmt]["rmse"] == pytest.approx(ates["tum"]["rmse"], rel=1e-9)
        assert ates[fmt]["n"] == 300
    assert 0.025 < ates["tum"]["rmse"] < 0.04  # 0.02 m noise per axis: about 0.035 m


def test_format_override_and_bad_files(files: dict[str, Path], tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["evaluate", str(files["tum"]), str(files["ref"]), "--format", "kitti"]
    )
    assert res.exit_code == 1 and "KITTI poses need 12 finite numbers per line" in res.output
    res = runner.invoke(app, ["evaluate", str(files["tum"]), str(files["ref"]), "--format", "x"])
    assert res.exit_code == 2 and "'--format': must be one of tum, euroc, kitti, bag" in res.output
    res = runner.invoke(
        app, ["evaluate", str(files["bag"]), str(files["ref"]), "--est-topic", "/x"]
    )
    assert res.exit_code == 1 and "/x (the gt topic): no such topic in the bag" in res.output
    odd = tmp_path / "odd.txt"
    odd.write_text("1 2 3 4 5\n")
    with pytest.raises(DatasetError, match="first row of 5 fields"):
        read_trajectory(odd)


def test_scaled_quaternions_are_normalised_and_a_header_without_hash_is_read(
    files: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Legal files evo reads (a user's probe): quaternions rounded or scaled (norm 1.01, 2)
    name one rotation each and are normalised with a warning; an EuRoC csv whose header lacks
    its '#' (pandas' to_csv) is read. A zero quaternion is still refused."""
    t, p, q = read_trajectory(files["tum"])
    scaled = tmp_path / "scaled.tum"
    write_tum(scaled, t, p, q * np.where(np.arange(t.size) % 2, 1.0, 2.0)[:, None])
    with caplog.at_level("WARNING", logger="svains.datasets.trajectory"):
        _, _, q2 = read_trajectory(scaled)
    np.testing.assert_allclose(q2, q, atol=1e-12)
    assert "150 quaternion(s) off unit norm by more than 0.01 (line" in caplog.text
    assert ": 2): normalised" in caplog.text
    text = files["euroc"].read_text()
    bare = tmp_path / "bare.csv"
    bare.write_text(text.lstrip("#"))
    t3, p3, _ = read_trajectory(bare, fmt="euroc")
    np.testing.assert_array_equal(t3, t)
    np.testing.assert_allclose(p3, p, atol=1e-12)
    zero = tmp_path / "zero.tum"
    zero.write_text("0.0 1 2 3 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"zero\.tum:1: quaternion norm 0: no rotation"):
        read_trajectory(zero)


def test_format_names_the_estimate_when_the_reference_is_a_data_set_folder(
    files: dict[str, Path], euroc_micro: Path
) -> None:
    """``--format tum`` against a data-set folder said "missing file: FOLDER" (a user's probe):
    the folder is read as a data set whatever --format says."""
    res = runner.invoke(app, ["evaluate", str(files["tum"]), str(euroc_micro), "--format", "tum"])
    assert res.exit_code == 0, res.output
    assert "300 matched poses" in res.output


def test_a_reference_folder_needs_only_its_ground_truth(
    files: dict[str, Path], euroc_micro: Path, tmp_path: Path
) -> None:
    """A Kalibr-calibrated ASL folder (no ``sensor.yaml`` files) as the reference was refused
    for its IMU's calibration, and ``evaluate`` has no ``--imu-calib`` (a user's probe): a
    reference folder is read for its ground truth alone."""
    mav = tmp_path / "kalibr" / "mav0"
    mav.mkdir(parents=True)
    for name in ("imu0", "cam0", "cam1"):  # the streams without their sensor.yaml
        (mav / name).mkdir()
        (mav / name / "data.csv").symlink_to(euroc_micro / "mav0" / name / "data.csv")
    (mav / "state_groundtruth_estimate0").symlink_to(
        euroc_micro / "mav0" / "state_groundtruth_estimate0")
    res = runner.invoke(app, ["evaluate", str(files["tum"]), str(tmp_path / "kalibr")])
    assert res.exit_code == 0, res.output
    assert "300 matched poses" in res.output
    t, p, q = read_trajectory(tmp_path / "kalibr", fmt="dataset")
    t0, p0, q0 = read_trajectory(euroc_micro, fmt="dataset")
    np.testing.assert_array_equal(t, t0)
    np.testing.assert_array_equal(p, p0)
    np.testing.assert_array_equal(q, q0)
