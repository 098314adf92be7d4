"""ROS bags without ROS: bags written from the EuRoC micro set read back as the same streams,
run like the folder, convert to an ASL folder, and bad input is refused with its reason."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from _kalibr_files import write_euroc_kalibr
from svains.cli.main import app
from svains.datasets import load_dataset
from svains.datasets.geodetic import geodetic_to_enu
from svains.datasets.kalibr import apply_kalibr
from svains.datasets.rosbag import bag_topics, read_bag, select_topics
from svains.datasets.rosbag_convert import convert_bag
from svains.datasets.rosbag_writer import write_bag
from svains.errors import ConfigError, DatasetError
from svains.evaluation.run import run_method
from svains.navigation.options import InitOptions, RunOptions, VisionOptions

BAG_SPAN_NS = 1_600_000_000  # 1.6 s of data after the first image: 32 stereo pairs


@pytest.fixture(scope="module")
def euroc(euroc_micro: Path):  # type: ignore[no-untyped-def]
    return load_dataset(euroc_micro)


@pytest.fixture(scope="module")
def kalibr(euroc, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:  # type: ignore[no-untyped-def]
    return write_euroc_kalibr(euroc, tmp_path_factory.mktemp("kalibr"))


@pytest.fixture(scope="module")
def ros1_bag(euroc, tmp_path_factory: pytest.TempPathFactory) -> Path:  # type: ignore[no-untyped-def]
    t_end = int(euroc.left.t_ns[0]) + BAG_SPAN_NS
    return write_bag(euroc, tmp_path_factory.mktemp("bag") / "micro.bag", "ros1", t_end_ns=t_end)


def _assert_same_streams(bag_ds, folder_ds) -> None:  # type: ignore[no-untyped-def]
    n = bag_ds.imu.t_ns.size
    np.testing.assert_array_equal(bag_ds.imu.t_ns, folder_ds.imu.t_ns[:n])
    np.testing.assert_array_equal(bag_ds.imu.gyro_B, folder_ds.imu.gyro_B[:n])
    np.testing.assert_array_equal(bag_ds.imu.accel_B, folder_ds.imu.accel_B[:n])
    for role in ("left", "right"):
        b, f = getattr(bag_ds, role), getattr(folder_ds, role)
        np.testing.assert_array_equal(b.t_ns, f.t_ns[: len(b)])
        np.testing.assert_array_equal(b.load(len(b) - 1), f.load(len(b) - 1))
    m = bag_ds.groundtruth.t_ns.size
    np.testing.assert_array_equal(bag_ds.groundtruth.p_W_B, folder_ds.groundtruth.p_W_B[:m])
    q = folder_ds.groundtruth.q_W_B_wxyz[:m]  # EuRoC's are unit only to 1e-6: normalised
    np.testing.assert_allclose(
        bag_ds.groundtruth.q_W_B_wxyz, q / np.linalg.norm(q, axis=1, keepdims=True), atol=1e-15
    )


def _run_3d(ds):  # type: ignore[no-untyped-def]
    opts = RunOptions(
        init=InitOptions(mode="static", static_s=0.5), duration_s=1.5,
        vision=VisionOptions(source="images", rotation="imu"),
    )  # fmt: skip
    return run_method(ds, "3d", opts)


def test_ros1_bag_with_kalibr_runs_like_the_folder(euroc, kalibr, ros1_bag: Path) -> None:  # type: ignore[no-untyped-def]
    ds = load_dataset(ros1_bag, calib=kalibr[0], imu_calib=kalibr[1])
    assert ds.extras["bag_topics"] == {
        "imu": "/imu0", "left": "/cam0/image_raw", "right": "/cam1/image_raw", "gt": "/groundtruth"
    }  # fmt: skip
    _assert_same_streams(ds, euroc)
    on_bag = _run_3d(ds)
    on_folder = _run_3d(apply_kalibr(euroc, *kalibr))
    assert on_bag.report["vision"]["frames_fused"] >= 15
    np.testing.assert_array_equal(on_bag.t_ns, on_folder.t_ns)
    np.testing.assert_allclose(on_bag.x, on_folder.x, rtol=0, atol=1e-9)
    # Against the folder's own sensor.yaml: T_B_C differs by float rounding (1e-16) through the
    # Kalibr inverse, which flips a few fixed-point remap roundings, hence a few features.
    on_sensor_yaml = _run_3d(euroc)
    assert np.abs(on_bag.x[:, :3] - on_sensor_yaml.x[:, :3]).max() < 5e-3


@pytest.mark.parametrize("fmt", ["mcap", "db3"])
def test_ros2_bags_read_the_same_streams(euroc, tmp_path: Path, fmt: str) -> None:  # type: ignore[no-untyped-def]
    t_end = int(euroc.left.t_ns[0]) + 300_000_000
    bag = write_bag(euroc, tmp_path / f"micro_{fmt}", fmt, t_end_ns=t_end)  # type: ignore[arg-type]
    target = next(bag.glob(f"*.{fmt}")) if fmt == "mcap" else bag  # a file or the bag folder
    ds = read_bag(target)
    assert len(ds.left) == 7 and ds.imu.t_ns.size == 61
    _assert_same_streams(ds, euroc)


def test_convert_writes_an_asl_folder_equal_to_the_bag(
    euroc, kalibr, ros1_bag: Path, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    calib = ["--calib", str(kalibr[0]), "--imu-calib", str(kalibr[1])]
    res = CliRunner().invoke(app, ["convert", str(ros1_bag), "--out", str(tmp_path / "a"), *calib])
    assert res.exit_code == 0, res.output
    assert "converted in" in res.output
    asl = load_dataset(tmp_path / "a")
    _assert_same_streams(asl, euroc)
    for ours, theirs in ((asl.cam0, euroc.cam0), (asl.cam1, euroc.cam1)):
        np.testing.assert_allclose(ours.T_B_C, theirs.T_B_C, atol=1e-12)
        np.testing.assert_array_equal(ours.distortion, theirs.distortion)
        assert ours.distortion_model == theirs.distortion_model == "radial-tangential"
    assert asl.imu_calib.gyro_noise_density == euroc.imu_calib.gyro_noise_density
    np.testing.assert_allclose(asl.groundtruth.bg_B, 0.0)  # pose-only ground truth: no biases


def test_convert_needs_the_calibration(kalibr, ros1_bag: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ConfigError, match=r"--calib camchain-imucam\.yaml"):
        convert_bag(ros1_bag, tmp_path / "a", imu_calib=kalibr[1])
    with pytest.raises(ConfigError, match=r"--imu-calib imu\.yaml"):
        convert_bag(ros1_bag, tmp_path / "b", calib=kalibr[0])
    res = CliRunner().invoke(app, ["convert", str(ros1_bag), "--out", str(tmp_path / "c")])
    assert res.exit_code == 1 and "error:" in res.output


def test_info_lists_topics_types_counts_and_rates(ros1_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "info.json"
    res = CliRunner().invoke(app, ["info", str(ros1_bag), "--json", str(out)], terminal_width=200)
    assert res.exit_code == 0, res.output
    info = json.loads(out.read_text())
    assert info["roles"]["imu"] == "/imu0"
    imu = next(t for t in info["topics"] if t["name"] == "/imu0")
    assert imu["count"] == 321 and imu["rate_hz"] == pytest.approx(200.0, rel=1e-3)
    line = next(ln for ln in res.output.splitlines() if "/imu0" in ln and "Imu" in ln)
    assert "sensor_msgs/msg/Imu" in line and "321" in line and "200.00" in line
    assert "auto-detected roles: imu=/imu0" in res.output


def test_topic_selection_refuses_ambiguity_and_wrong_types(ros1_bag: Path) -> None:
    topics = bag_topics(ros1_bag)
    doubled = [*topics, type(topics[0])("/imu1", "sensor_msgs/msg/Imu", 5, 200.0, 0.02)]
    with pytest.raises(ConfigError, match=r"several imu topics \(/imu0, /imu1\): pass --topic"):
        select_topics(doubled)
    assert select_topics(doubled, {"imu": "/imu1"})["imu"] == "/imu1"
    with pytest.raises(ConfigError,
                       match=r"/cam0/image_raw \(the imu topic\): type sensor_msgs/msg/Image"):
        select_topics(topics, {"imu": "/cam0/image_raw"})
    with pytest.raises(ConfigError,
                       match=r"/nope \(the gt topic\): no such topic in the bag \(its topics: "):
        select_topics(topics, {"gt": "/nope"})
    unnamed = [t for t in topics if "image" not in t.name] + [
        type(topics[0])("/a", "sensor_msgs/msg/Image", 3, 20.0, 0.1),
        type(topics[0])("/b", "sensor_msgs/msg/Image", 3, 20.0, 0.1),
    ]
    # the hint names --topic, convert's option and the camchain's rostopic
    with pytest.raises(ConfigError, match=r"cannot tell the left camera among image topics /a, "
                       r"/b: pass --topic left=TOPIC \(run, compare, info, frontend; svains "
                       r"convert: --left TOPIC\), or give it as rostopic of cam0 in the "
                       r"camchain \(--calib\)"):  # fmt: skip
        select_topics(unnamed)
    # a role given against the calibration's rostopic (cam0's intrinsics on the right images)
    hints = {"left": "/a", "right": "/b"}
    with pytest.raises(ConfigError, match=r"/b \(the left topic\): the calibration's rostopic "
                       r"makes it the right topic"):  # fmt: skip
        select_topics(unnamed, {"left": "/b", "right": "/a"}, hints)
    assert select_topics(unnamed, {"left": "/a"}, hints)["right"] == "/b"


def test_broken_bag_is_a_dataset_error(tmp_path: Path) -> None:
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"#ROSBAG V2.0\nnot a bag")
    with pytest.raises(DatasetError, match=r"broken\.bag: cannot read bag"):
        load_dataset(bad)


def test_navsatfix_becomes_local_enu(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Fix, Status = T["sensor_msgs/msg/NavSatFix"], T["sensor_msgs/msg/NavSatStatus"]
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    fixes = [(0.0, 0.0, 10.0, 0), (0.001, 0.0, 10.0, 0), (0.001, 0.001, 12.0, 0), (5.0, 5.0, 0, -1)]
    path = tmp_path / "gps"
    with Writer(path, version=9) as w:
        c = w.add_connection("/fix", Fix.__msgtype__, typestore=ts)
        for k, (lat, lon, alt, st) in enumerate(fixes):
            t = (k + 1) * 1_000_000_000
            cov = np.diag([4.0, 4.0, 9.0]).reshape(-1) * (k + 1)
            msg = Fix(Header(Time(sec=k + 1, nanosec=0), "gps"), Status(status=st, service=1),
                      lat, lon, alt, cov, 2)  # fmt: skip
            w.write(c, t, ts.serialize_cdr(msg, Fix.__msgtype__))
    ds = read_bag(path)
    assert ds.gps.t_ns.size == 3  # the NO_FIX message is dropped
    # WGS-84 at the equator: 110,574 m per degree of latitude, 111,319 m per degree of longitude.
    np.testing.assert_allclose(ds.gps.p_W_G[1], [0.0, 110.574, 0.0], atol=2e-3)
    np.testing.assert_allclose(ds.gps.p_W_G[2, :2], [111.319, 110.574], atol=2e-3)
    assert ds.gps.p_W_G[2, 2] == pytest.approx(2.0, abs=2e-3)
    assert ds.gps_calib.position_noise_std == pytest.approx(np.sqrt(17 / 3 * 2), rel=1e-12)
    # a NavSatFix has no velocity: none is made up from the positions
    assert not ds.gps.has_velocity.any()
    np.testing.assert_allclose(geodetic_to_enu(0.0, 0.0, 10.0, (0.0, 0.0, 10.0)), 0.0, atol=1e-9)


def test_image_messages_decode_to_grey() -> None:
    import cv2

    from svains.datasets._image_io import decode_compressed, decode_raw

    rng = np.random.default_rng(3)
    grey = rng.integers(0, 256, size=(4, 6), dtype=np.uint8)
    padded = np.zeros((4, 8), np.uint8)
    padded[:, :6] = grey  # a row step wider than the image
    np.testing.assert_array_equal(decode_raw("mono8", 4, 6, 8, padded.tobytes()), grey)
    wide = (grey.astype("<u2") << 8) | 0xAB
    np.testing.assert_array_equal(decode_raw("mono16", 4, 6, 12, wide.tobytes()), grey)
    bgr = rng.integers(0, 256, size=(4, 6, 3), dtype=np.uint8)
    np.testing.assert_array_equal(
        decode_raw("bgr8", 4, 6, 18, bgr.tobytes()), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )
    ok, png = cv2.imencode(".png", grey)
    assert ok
    np.testing.assert_array_equal(decode_compressed(png.tobytes()), grey)
    with pytest.raises(DatasetError, match="image encoding 'bayer_rggb8' is not supported"):
        decode_raw("bayer_rggb8", 4, 6, 6, grey.tobytes())


def test_a_folder_that_is_no_bag_says_so(tmp_path: Path) -> None:
    """``svains convert`` on an ASL folder said "Expected metadata file … does not exist"."""
    from svains.datasets.rosbag import bag_topics
    from svains.errors import DatasetError

    (tmp_path / "mav0").mkdir()
    with pytest.raises(DatasetError, match=r"a folder without a ROS2 metadata\.yaml, so not a "
                       r"bag \(an ASL/EuRoC or KITTI data set is read as it is"):  # fmt: skip
        bag_topics(tmp_path)


def test_ambiguous_topics_are_chosen_with_topic_on_info_run_and_compare(
    euroc, tmp_path: Path  # type: ignore[no-untyped-def]
) -> None:
    """Image topics named neither cam0/left nor cam1/right: `svains info` says how to choose,
    and `--topic ROLE=TOPIC` chooses on info and run (the docs named options that only
    `convert` has: a user's probe), kept in config.yaml; a bad item is a usage error."""
    t_end = int(euroc.left.t_ns[0]) + 600_000_000
    bag = write_bag(euroc, tmp_path / "odd.bag", "ros1",
                    topics={"left": "/front/a", "right": "/front/b"}, t_end_ns=t_end)  # fmt: skip
    runner = CliRunner()
    res = runner.invoke(app, ["info", str(bag)], terminal_width=200)
    assert res.exit_code == 0, res.output
    assert "pass --topic left=TOPIC" in res.output
    chosen = ["--topic", "left=/front/a", "--topic", "right=/front/b"]
    res = runner.invoke(app, ["info", str(bag), *chosen, "--json", str(tmp_path / "i.json")],
                        terminal_width=200)  # fmt: skip
    assert res.exit_code == 0, res.output
    roles = json.loads((tmp_path / "i.json").read_text())["roles"]
    assert roles["left"] == "/front/a" and roles["right"] == "/front/b"
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", str(bag), "--method", "ins", "--init", "groundtruth",
                              "--no-gps", "--no-mag", "--out", str(out), *chosen],
                        terminal_width=200)  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "topics: left=/front/a,right=/front/b" in (out / "config.yaml").read_text()
    res = runner.invoke(app, ["run", str(bag), "--method", "ins", "--out", str(tmp_path / "x"),
                              "--topic", "lefty=/front/a"], terminal_width=200)  # fmt: skip
    assert res.exit_code == 2 and "unknown role 'lefty'" in res.output
    assert not (tmp_path / "x").exists()
    folder = runner.invoke(app, ["info", str(euroc.root), "--topic", "left=/front/a"],
                           terminal_width=200)  # fmt: skip
    assert folder.exit_code == 1 and "is not a bag" in folder.output
