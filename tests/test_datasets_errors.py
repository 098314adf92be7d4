"""Bad input gets a clear, typed error (or one warning for absent images); messages checked."""

from __future__ import annotations

import logging
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.errors import CalibrationError, DatasetError
from test_datasets_roundtrip import write_full


@pytest.fixture
def ds_dir(tmp_path: Path) -> Path:
    write_full(tmp_path / "ds")
    return tmp_path / "ds"


def _edit_line(path: Path, line_no: int, new: str) -> None:
    lines = path.read_text().splitlines()
    lines[line_no - 1] = new
    path.write_text("\n".join(lines) + "\n")


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"data set folder not found: .*nowhere"):
        load_dataset(tmp_path / "nowhere")


def test_unrecognised_folder(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="unrecognised data set"):
        load_dataset(tmp_path / "empty")


@pytest.mark.parametrize(
    "rel", ["mav0/cam0/data.csv", "mav0/imu0/sensor.yaml", "mav0/gps0/data.csv"]
)
def test_missing_file(ds_dir: Path, rel: str) -> None:
    (ds_dir / rel).unlink()
    with pytest.raises(DatasetError, match=f"missing file: .*{re.escape(rel)}"):
        load_dataset(ds_dir)


def test_malformed_row_names_file_and_line(ds_dir: Path) -> None:
    _edit_line(ds_dir / "mav0/imu0/data.csv", 5, "1403715273282142976,0.1,0.2")
    with pytest.raises(DatasetError, match=r"imu0/data\.csv:5: malformed row, expected 7 fields"):
        load_dataset(ds_dir)


def test_malformed_number_names_file_and_line(ds_dir: Path) -> None:
    path = ds_dir / "mav0/state_groundtruth_estimate0/data.csv"
    fields = path.read_text().splitlines()[3].split(",")
    fields[4] = "abc"
    _edit_line(path, 4, ",".join(fields))
    with pytest.raises(DatasetError, match=r"estimate0/data\.csv:4: malformed number 'abc'"):
        load_dataset(ds_dir)


def test_malformed_timestamp(ds_dir: Path) -> None:
    path = ds_dir / "mav0/sonar0/data.csv"
    _edit_line(path, 2, "12.5e9,1.0")
    with pytest.raises(DatasetError,
                       match=r"sonar0/data\.csv:2: malformed timestamp '12.5e9'") as e:
        load_dataset(ds_dir)
    assert "looks like seconds" not in str(e.value)


def test_decimal_seconds_stamps_are_named_with_their_nanoseconds(ds_dir: Path) -> None:
    """A user's export in seconds with decimals got only "expected integer nanoseconds"."""
    path = ds_dir / "mav0/sonar0/data.csv"
    _edit_line(path, 2, "1700000000.250000,1.0")
    with pytest.raises(DatasetError, match=r"sonar0/data\.csv:2: malformed timestamp "
                       r"'1700000000\.250000' \(expected integer nanoseconds; 1700000000\.250000 "
                       r"looks like seconds with decimals: write integer nanoseconds, "
                       r"1700000000250000000 here\)"):  # fmt: skip
        load_dataset(ds_dir)


def test_stream_folders_under_other_names_are_named(
    ds_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """``imu/``, ``left/``, ``right/`` (a user's export): ``info`` listed the ground truth alone
    and said nothing of the folders it did not read."""
    mav = ds_dir / "mav0"
    for old, new in (("imu0", "imu"), ("cam0", "left"), ("cam1", "right")):
        (mav / old).rename(mav / new)
    (mav / "leica0").mkdir()  # EuRoC's own, not read and not named
    with caplog.at_level(logging.WARNING, logger="svains.datasets.asl_reader"):
        ds = load_dataset(ds_dir)
    assert ds.imu is None and ds.left is None
    assert caplog.text.count("are not read") == 1
    assert ("folder(s) imu/, left/, right/ are not read: the streams are read from imu0/, cam0/ "
            "(left), cam1/ (right)") in caplog.text
    assert "(imu0/, cam0/, cam1/ missing here); rename them" in caplog.text
    assert "leica0" not in caplog.text


def test_duplicate_timestamp(ds_dir: Path) -> None:
    path = ds_dir / "mav0/imu0/data.csv"
    lines = path.read_text().splitlines()
    lines[3] = lines[2]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"imu0/data\.csv:4: duplicate timestamp"):
        load_dataset(ds_dir)


def test_non_increasing_timestamp(ds_dir: Path) -> None:
    path = ds_dir / "mav0/mag0/data.csv"
    lines = path.read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"mag0/data\.csv:5: non-increasing timestamp"):
        load_dataset(ds_dir)


def test_nan_value(ds_dir: Path) -> None:
    path = ds_dir / "mav0/imu0/data.csv"
    fields = path.read_text().splitlines()[2].split(",")
    fields[3] = "nan"
    _edit_line(path, 3, ",".join(fields))
    with pytest.raises(DatasetError, match=r"imu0/data\.csv:3: NaN or infinite value"):
        load_dataset(ds_dir)


def test_duplicate_feature_observation(ds_dir: Path) -> None:
    path = ds_dir / "mav0/features0/data.csv"
    lines = path.read_text().splitlines()
    lines[2] = lines[1]
    path.write_text("\n".join(lines) + "\n")
    ds = load_dataset(ds_dir)  # features0 is parsed on first access, not by the loader
    assert ds.has_stream("features")
    with pytest.raises(DatasetError, match=r"features0/data\.csv:3: duplicate observation of trac"):
        _ = ds.features
    # Still there, still failing: a failed read is not cached as absent.
    assert ds.has_stream("features")
    with pytest.raises(DatasetError, match="duplicate observation"):
        _ = ds.features


def test_data_set_with_deferred_features_pickles(ds_dir: Path) -> None:
    import pickle

    ds = load_dataset(ds_dir)
    back = pickle.loads(pickle.dumps(ds))  # the deferred reader travels, unread
    assert back.has_stream("features")
    np.testing.assert_array_equal(back.features.uv_left, ds.features.uv_left)


def test_features_are_read_on_first_access_only(
    ds_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import svains.datasets.asl_reader as reader

    calls: list[Path] = []
    real = reader.read_features

    def counting(folder: Path, timeshift_cam_imu_s: float = 0.0) -> object:
        calls.append(folder)
        return real(folder, timeshift_cam_imu_s)

    monkeypatch.setattr(reader, "read_features", counting)
    ds = load_dataset(ds_dir)
    assert calls == [] and ds.has_stream("features") and ds.has_stream("imu")
    first = ds.features
    assert ds.features is first and calls == [ds_dir / "mav0/features0"]
    with pytest.raises(ValueError, match="stream 'imu' cannot be deferred"):
        ds.defer("imu", lambda: None)
    shutil.rmtree(ds_dir / "mav0/features0")
    assert not load_dataset(ds_dir).has_stream("features")


def test_absent_images_warn_once_and_skip(ds_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    for cam, k in (("cam0", 0), ("cam0", 2), ("cam1", 1)):
        sorted((ds_dir / f"mav0/{cam}/data").iterdir())[k].unlink()
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(ds_dir)
    msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(msgs) == 1
    assert "3 image(s) listed in data.csv but absent on disk, skipped (cam0: 2, cam1: 1)" in msgs[0]
    assert ds.missing_images == {"cam0": 2, "cam1": 1}
    assert len(ds.left) == 2 and len(ds.right) == 3
    assert all(p.is_file() for p in ds.left.paths)


def test_unreadable_image_names_the_file(ds_dir: Path) -> None:
    first = sorted((ds_dir / "mav0/cam0/data").iterdir())[0]
    first.write_bytes(b"not a png at all")
    ds = load_dataset(ds_dir)  # listing does not decode
    with pytest.raises(DatasetError, match=f"unreadable image: .*{re.escape(first.name)}"):
        ds.left.load(0)


def test_an_image_cut_short_is_named_before_the_decoder_prints(
    ds_dir: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A PNG cut short: the error says why, and libpng's own "Read Error" lines (on the
    process's stderr, beside the run's warnings) are not printed: the decoder never sees it."""
    first = sorted((ds_dir / "mav0/cam0/data").iterdir())[0]
    ds = load_dataset(ds_dir)
    whole = ds.left.load(0)
    first.write_bytes(first.read_bytes()[: first.stat().st_size // 2])
    with pytest.raises(DatasetError, match=f"unreadable image: .*{re.escape(first.name)}: no PNG "
                       r"end chunk \(cut short\?\)"):  # fmt: skip
        ds.left.load(0)
    assert capfd.readouterr().err == ""
    assert whole.shape == (24, 32)


def test_camera_yaml_without_intrinsics(ds_dir: Path) -> None:
    path = ds_dir / "mav0/cam1/sensor.yaml"
    text = "\n".join(ln for ln in path.read_text().splitlines() if not ln.startswith("intrinsics"))
    path.write_text(text + "\n")
    with pytest.raises(
        CalibrationError, match=r"cam1/sensor\.yaml: camera calibration without 'int"
    ):
        load_dataset(ds_dir)


def test_imu_yaml_missing_noise_field(ds_dir: Path) -> None:
    path = ds_dir / "mav0/imu0/sensor.yaml"
    text = "\n".join(ln for ln in path.read_text().splitlines() if "gyroscope_noise" not in ln)
    path.write_text(text + "\n")
    with pytest.raises(CalibrationError, match="missing field 'gyroscope_noise_density'"):
        load_dataset(ds_dir)


@pytest.fixture
def kitti_dir(tmp_path: Path) -> Path:
    d = tmp_path / "kitti"
    for sub in ("image_0", "image_1"):
        (d / sub).mkdir(parents=True)
    from svains.datasets._image_io import write_grey

    for i in range(3):
        for sub in ("image_0", "image_1"):
            write_grey(d / sub / f"{i:06d}.png", np.full((4, 6), i, np.uint8))
    p0 = "P0: 700 0 300 0 0 700 180 0 0 0 1 0"
    p1 = "P1: 700 0 300 -350 0 700 180 0 0 0 1 0"
    (d / "calib.txt").write_text(f"{p0}\n{p1}\n")
    (d / "times.txt").write_text("0.0\n0.1\n0.2\n")
    pose = "1 0 0 {x} 0 1 0 0 0 0 1 {z}"
    (d / "poses.txt").write_text("\n".join(pose.format(x=0, z=i) for i in range(3)) + "\n")
    return d


def test_kitti_minimal(kitti_dir: Path) -> None:
    ds = load_dataset(kitti_dir)
    assert ds.cam1.T_B_C[0, 3] == 0.5 and ds.cam0.resolution == (6, 4)
    np.testing.assert_allclose(ds.groundtruth.v_W_B[:, 2], 10.0)


def test_kitti_missing_p1(kitti_dir: Path) -> None:
    (kitti_dir / "calib.txt").write_text("P0: 700 0 300 0 0 700 180 0 0 0 1 0\n")
    with pytest.raises(CalibrationError, match="missing projection matrix 'P1:'"):
        load_dataset(kitti_dir)


def test_kitti_missing_calib(kitti_dir: Path) -> None:
    (kitti_dir / "calib.txt").unlink()
    with pytest.raises(DatasetError, match=r"missing file: .*calib\.txt"):
        load_dataset(kitti_dir)


def test_kitti_missing_times(kitti_dir: Path) -> None:
    (kitti_dir / "times.txt").unlink()
    with pytest.raises(DatasetError, match=r"missing file: .*times\.txt"):
        load_dataset(kitti_dir)


def test_kitti_pose_count_mismatch(kitti_dir: Path) -> None:
    (kitti_dir / "times.txt").write_text("0.0\n0.1\n0.2\n0.3\n")
    shutil.copy(kitti_dir / "image_0/000000.png", kitti_dir / "image_0/000003.png")
    with pytest.raises(DatasetError, match="3 poses for 4 timestamps"):
        load_dataset(kitti_dir)


def test_kitti_nan_pose(kitti_dir: Path) -> None:
    (kitti_dir / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 nan\n" * 3)
    with pytest.raises(DatasetError, match=r"poses\.txt:1: NaN"):
        load_dataset(kitti_dir)


def test_kitti_non_increasing_times(kitti_dir: Path) -> None:
    (kitti_dir / "times.txt").write_text("0.0\n0.2\n0.2\n")
    with pytest.raises(DatasetError, match=r"times\.txt:3: non-increasing timestamp"):
        load_dataset(kitti_dir)


def test_malformed_extra_is_skipped_with_warning(
    ds_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = ds_dir / "mav0/state_groundtruth_estimate0/kinematics.csv"
    _edit_line(path, 3, "123,1.0")
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(ds_dir)
    assert "kinematics" not in ds.extras
    assert any(
        "simulator extra skipped" in r.getMessage() and "kinematics.csv:3" in r.getMessage()
        for r in caplog.records
    )


def test_an_image_of_another_size_drops_its_pair_with_a_warning(
    ds_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from svains.datasets import stereo_pairs
    from svains.datasets._image_io import write_grey
    from svains.datasets.loader import PairReader

    ds = load_dataset(ds_dir)  # the load checks the first image's size only
    t, il, ir = stereo_pairs(ds)
    write_grey(ds.right.paths[int(ir[1])], np.zeros((12, 16), np.uint8))
    reader = PairReader(ds)
    with caplog.at_level("WARNING", logger="svains.datasets.loader"):
        got = [reader.read(a, b, ti) for ti, a, b in zip(t, il, ir, strict=True)]
    assert got[1] is None and all(g is not None for i, g in enumerate(got) if i != 1)
    assert reader.dropped == 1
    assert re.search(r"stereo pair dropped \(1 so far\): image is 16x12 px, the calibration's "
                     r"resolution is 32x24: .*cam1", caplog.text)  # fmt: skip


def _write_features(path: Path, uv: np.ndarray) -> None:
    rows = [f"{k // 20 * 50_000_000},{k % 20},{u1},{v1},{u2},{v2}"
            for k, (u1, v1, u2, v2) in enumerate(uv)]  # fmt: skip
    path.write_text("#timestamp,track_id,u_left,v_left,u_right,v_right\n" + "\n".join(rows) + "\n")


def test_feature_columns_swapped_are_refused_and_rows_apart_warned(
    ds_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """features0 with u_left and u_right crossed ran to the end with only "fused no vision"
    (a user's probe): refused naming the columns. Pixels rows apart (not a rectified pair) are
    warned; a right file is read silently, its far points (under 1 px of disparity) aside."""
    rng = np.random.default_rng(3)
    n = 100
    u_l, v = rng.uniform(50, 700, n), rng.uniform(20, 460, n)
    d = rng.uniform(2.0, 40.0, n)
    d[:10] = rng.uniform(-0.9, 0.9, 10)  # far points: no say
    right = np.column_stack([u_l, v, u_l - d, v + rng.normal(0, 0.5, n)])
    path = ds_dir / "mav0/features0/data.csv"
    with caplog.at_level(logging.WARNING, logger="svains.datasets.validate"):
        _write_features(path, right)
        assert load_dataset(ds_dir).features.uv_left.shape == (n, 2)
        assert caplog.text == ""
        _write_features(path, right[:, [0, 1, 2, 3]] + np.array([0.0, 0.0, 0.0, 6.0]))
        _ = load_dataset(ds_dir).features
    assert re.search(r"features0/data\.csv: left and right pixels are 6\.\d px apart in rows "
                     r"\(median of 9\d\)", caplog.text)  # fmt: skip
    _write_features(path, right[:, [2, 3, 0, 1]])
    with pytest.raises(DatasetError, match=r"features0/data\.csv: 90 of 90 observations lie at "
                       r"negative disparity \(u_right right of u_left\): are the left and right "
                       r"columns swapped\?"):  # fmt: skip
        _ = load_dataset(ds_dir).features
