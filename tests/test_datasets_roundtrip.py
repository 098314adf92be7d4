"""AslWriter -> load_dataset round trip: every stream comes back bit-exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets import AslWriter, iter_events, load_dataset, stereo_pairs
from svains.datasets._textio import format_float, read_sensor_yaml
from svains.datasets.types import (
    CameraCalib,
    FeatureStream,
    GpsCalib,
    GpsStream,
    GroundTruth,
    ImuCalib,
    ImuStream,
    MagCalib,
    MagStream,
    SonarCalib,
    SonarStream,
)
from svains.errors import CalibrationError


def _T(rng: np.random.Generator) -> np.ndarray:
    T = np.eye(4)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T[:3, :3] = q * np.sign(np.linalg.det(q))
    T[:3, 3] = rng.normal(size=3)
    return T


def write_full(root: Path, seed: int = 0) -> dict[str, object]:
    """A small synthetic data set with every stream; returns what was written."""
    rng = np.random.default_rng(seed)
    w = AslWriter(root)
    t0 = 1_403_715_273_262_142_976  # beyond float64's exact integers on purpose
    t_imu = t0 + np.arange(40, dtype=np.int64) * 5_000_000
    # specific force about 1 g: the reader refuses an accelerometer in another unit
    accel = rng.normal(size=(40, 3)) + np.array([0.0, 0.0, 9.81])
    imu = ImuStream(t_imu, rng.normal(size=(40, 3)) * 1e-7, accel)
    imu_cal = ImuCalib(_T(rng), 200.0, 1.6968e-4, 1.9393e-05, 2e-3, 3e-3, 17.45, 176.5)
    t_cam = t_imu[::10]
    cams = []
    for name, T in (("cam0", np.eye(4)), ("cam1", _T(rng))):
        cal = CameraCalib(
            name, T, 20.0, (32, 24), np.array([458.654, 457.296, 16.1, 12.2]),
            "radial-tangential", np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]),
        )  # fmt: skip
        images = [rng.integers(0, 256, size=(24, 32), dtype=np.uint8) for _ in t_cam]
        w.write_camera(cal, t_cam, iter(images))
        cams.append((cal, images))
    n = 8
    t_gt = t0 + np.arange(n, dtype=np.int64) * 50_000_000
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    gt = GroundTruth(t_gt, rng.normal(size=(n, 3)), q, *(rng.normal(size=(n, 3)) for _ in "vba"))
    gps = GpsStream(t_gt, rng.normal(size=(n, 3)) * 100, rng.normal(size=(n, 3)))
    gps_cal = GpsCalib(np.array([0.1, -0.2, 0.3]), 20.0, 1.5, 0.1, position_correlation_s=12.5)
    mag = MagStream(t_gt, rng.normal(size=(n, 3)))
    mag_cal = MagCalib(_T(rng), 20.0, np.array([0.2, 0.0, -0.4]), 1e-3)
    sonar = SonarStream(t_gt, rng.uniform(0.5, 3.0, n))
    sonar_cal = SonarCalib(_T(rng), 20.0, 0.01, 0.0)
    tf = np.repeat(t_cam, 3)
    feats = FeatureStream(
        tf, np.tile(np.arange(3, dtype=np.int64), t_cam.size), rng.uniform(0, 32, (tf.size, 2)),
        rng.uniform(0, 32, (tf.size, 2)), 0.5,
    )  # fmt: skip
    w.write_body([0.0, 0.0, -9.80665])
    w.write_imu(imu, imu_cal)
    w.write_groundtruth(gt)
    w.write_gps(gps, gps_cal)
    w.write_mag(mag, mag_cal)
    w.write_sonar(sonar, sonar_cal)
    w.write_features(feats)
    kin = rng.normal(size=(n, 12))
    lm_ids = np.arange(5, dtype=np.int64) * 7
    lm_p = rng.normal(size=(5, 3)) * 20
    w.write_csv_extra("state_groundtruth_estimate0", "landmarks.csv", "id,x,y,z", [lm_ids, lm_p])
    w.write_csv_extra("state_groundtruth_estimate0", "kinematics.csv", "timestamp,...", [t_gt, kin])
    return dict(
        imu=imu, imu_cal=imu_cal, cams=cams, gt=gt, gps=gps, gps_cal=gps_cal, mag=mag,
        mag_cal=mag_cal, sonar=sonar, sonar_cal=sonar_cal, feats=feats, kin=kin,
        lm_ids=lm_ids, lm_p=lm_p,
    )  # fmt: skip


def _eq(a: object, b: object) -> None:
    for k, v in vars(a).items():
        if k == "loader":
            continue
        other = getattr(b, k)
        if isinstance(v, np.ndarray):
            np.testing.assert_array_equal(v, other, err_msg=k)
            assert np.asarray(other).dtype.kind == v.dtype.kind, k
        else:
            assert v == other, k


def test_round_trip_every_stream_bit_exact(tmp_path: Path) -> None:
    src = write_full(tmp_path / "ds")
    ds = load_dataset(tmp_path / "ds")
    np.testing.assert_array_equal(ds.gravity_W, [0.0, 0.0, -9.80665])
    _eq(src["imu"], ds.imu)
    _eq(src["imu_cal"], ds.imu_calib)
    _eq(src["gt"], ds.groundtruth)
    _eq(src["gps"], ds.gps)
    _eq(src["gps_cal"], ds.gps_calib)
    _eq(src["mag"], ds.mag)
    _eq(src["mag_cal"], ds.mag_calib)
    _eq(src["sonar"], ds.sonar)
    _eq(src["sonar_cal"], ds.sonar_calib)
    _eq(src["feats"], ds.features)
    for (cal, images), stream, got in zip(
        src["cams"], (ds.left, ds.right), (ds.cam0, ds.cam1), strict=True
    ):
        _eq(cal, got)
        assert len(stream) == len(images)
        for i, img in enumerate(images):
            np.testing.assert_array_equal(stream.load(i), img)
    kin = ds.extras["kinematics"]
    np.testing.assert_array_equal(kin["f_B"], src["kin"][:, 9:12])
    np.testing.assert_array_equal(kin["t_ns"], src["gt"].t_ns)
    np.testing.assert_array_equal(ds.extras["landmarks"]["id"], src["lm_ids"])
    np.testing.assert_array_equal(ds.extras["landmarks"]["p_W_F"], src["lm_p"])
    assert ds.missing_images == {}
    # mav0/ itself is accepted as the root too.
    assert load_dataset(tmp_path / "ds" / "mav0").imu.t_ns[0] == src["imu"].t_ns[0]


def test_sensor_yaml_is_kalibr_style(tmp_path: Path) -> None:
    write_full(tmp_path / "ds")
    text = (tmp_path / "ds/mav0/cam0/sensor.yaml").read_text()
    assert text.startswith("%YAML:1.0\n")
    assert "T_BS:\n  cols: 4\n  rows: 4\n  data: [" in text
    y = read_sensor_yaml(tmp_path / "ds/mav0/cam0/sensor.yaml")
    assert y["camera_model"] == "pinhole"
    assert y["distortion_model"] == "radial-tangential"
    assert y["resolution"] == [32, 24]


@pytest.mark.parametrize("x", [1e-05, 3e20, -0.1, 1.0, 1 / 3, 5e-324])
def test_format_float_reads_back_exactly_as_yaml_float(x: float) -> None:
    import yaml

    assert yaml.safe_load(f"v: {format_float(x)}")["v"] == x


def test_writer_rejects_image_count_mismatch(tmp_path: Path) -> None:
    cal = CameraCalib("cam0", np.eye(4), 20.0, (4, 4), np.ones(4), "radial-tangential", np.zeros(4))
    img = np.zeros((4, 4), np.uint8)
    with pytest.raises(ValueError, match="1 images for 2 timestamps"):
        AslWriter(tmp_path).write_camera(cal, np.array([1, 2]), [img])


def test_iter_events_time_order_imu_first_and_window(tmp_path: Path) -> None:
    write_full(tmp_path / "ds")
    ds = load_dataset(tmp_path / "ds")
    ev = list(iter_events(ds))
    t = np.array([e[0] for e in ev])
    assert np.all(np.diff(t) >= 0)
    n_total = sum(
        x.t_ns.size for x in (ds.imu, ds.left, ds.right, ds.groundtruth, ds.gps, ds.mag, ds.sonar)
    )
    assert len(ev) == n_total + ds.features.frame_times().size
    first_t = [e for e in ev if e[0] == t[0]]
    assert first_t[0][1] == "imu"
    assert {e[1] for e in first_t} == {
        "imu", "groundtruth", "gps", "mag", "sonar", "left", "right", "features"
    }  # fmt: skip
    t1, t20 = int(ds.imu.t_ns[1]), int(ds.imu.t_ns[20])
    sub = list(iter_events(ds, streams=["left", "imu"], t_start_ns=t1, t_end_ns=t20))
    assert {e[1] for e in sub} == {"imu", "left"}
    assert [e[2] for e in sub if e[1] == "imu"] == list(range(1, 21))
    assert [e[2] for e in sub if e[1] == "left"] == [1, 2]
    with pytest.raises(ValueError, match="unknown stream 'lidar'"):
        list(iter_events(ds, streams=["lidar"]))


def test_stereo_pairs_drop_unpaired(tmp_path: Path) -> None:
    write_full(tmp_path / "ds")
    (tmp_path / "ds/mav0/cam1/data").joinpath(
        sorted(p.name for p in (tmp_path / "ds/mav0/cam1/data").iterdir())[1]
    ).unlink()
    ds = load_dataset(tmp_path / "ds")
    t, il, ir = stereo_pairs(ds)
    assert t.size == 3 and il.tolist() == [0, 2, 3] and ir.tolist() == [0, 1, 2]
    np.testing.assert_array_equal(ds.left.t_ns[il], ds.right.t_ns[ir])


def test_png_images_are_stored_without_deflate(tmp_path: Path) -> None:
    """Written PNGs use zlib level 0 (EuRoC's choice): readers skip the inflate cost."""
    import struct
    import zlib

    from svains.datasets._image_io import read_grey, write_grey

    img = np.tile(np.arange(64, dtype=np.uint8), (48, 1))  # very compressible on purpose
    write_grey(tmp_path / "a.png", img)
    data = (tmp_path / "a.png").read_bytes()
    idat, pos = b"", 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        if data[pos + 4 : pos + 8] == b"IDAT":
            idat += data[pos + 8 : pos + 8 + length]
        pos += 12 + length
    # zlib header FLEVEL bits (0 = fastest/stored) and the first deflate block type (00 = stored).
    assert idat[1] >> 6 == 0
    assert idat[2] & 0b110 == 0
    assert len(zlib.decompress(idat)) == img.shape[0] * (img.shape[1] + 1)
    np.testing.assert_array_equal(read_grey(tmp_path / "a.png"), img)


def test_gps_timeshift_moves_fixes_to_the_imu_clock_and_round_trips(tmp_path: Path) -> None:
    """``timeshift_gps_imu`` in ``gps0/sensor.yaml``: t_imu = t_gps + shift, applied once on
    reading; the writer puts the stamps back on the receiver's clock with the key, so a
    round trip gives the same fixes and calibration. A non-finite shift names file and key."""
    t_imu = np.arange(1, 6, dtype=np.int64) * 1_000_000_000
    p = np.arange(15.0).reshape(5, 3)
    cal = GpsCalib(np.zeros(3), 1.0, 0.5, 0.1, timeshift_gps_imu_s=-0.1)
    AslWriter(tmp_path / "a").write_gps(GpsStream(t_imu, p, -p), cal)
    raw = np.loadtxt(tmp_path / "a" / "mav0" / "gps0" / "data.csv", delimiter=",",
                     dtype=np.int64, usecols=0)  # fmt: skip
    np.testing.assert_array_equal(raw, t_imu + 100_000_000)  # stamped 0.1 s late
    ds = load_dataset(tmp_path / "a")
    assert ds.gps is not None and ds.gps_calib is not None
    np.testing.assert_array_equal(ds.gps.t_ns, t_imu)
    assert ds.gps_calib.timeshift_gps_imu_s == -0.1
    yaml_path = tmp_path / "a" / "mav0" / "gps0" / "sensor.yaml"
    yaml_path.write_text(yaml_path.read_text().replace("-0.1", ".nan"))
    with pytest.raises(CalibrationError, match=r"gps0/sensor\.yaml: field 'timeshift_gps_imu' "
                       r"must be finite, is nan"):  # fmt: skip
        load_dataset(tmp_path / "a")


def test_csv_written_in_chunks_is_the_same_file(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``write_csv`` formats ``CSV_CHUNK_ROWS`` rows at a time (a simulated hour of features
    built as one string took 10 GB): the file is the same whatever the chunk."""
    from svains.datasets import _textio

    rng = np.random.default_rng(0)
    blocks = [np.arange(1001, dtype=np.int64) * 5, rng.standard_normal((1001, 2)),
              np.array(["a", "b"] * 500 + ["c"])]  # fmt: skip
    _textio.write_csv(tmp_path / "whole.csv", "t,x,y,s", blocks)
    monkeypatch.setattr(_textio, "CSV_CHUNK_ROWS", 7)
    _textio.write_csv(tmp_path / "chunks.csv", ["t", "x", "y", "s"], blocks)
    text = (tmp_path / "chunks.csv").read_text()
    assert text == (tmp_path / "whole.csv").read_text()
    assert text.count("\n") == 1002 and text.startswith("#t,x,y,s\n0,")
