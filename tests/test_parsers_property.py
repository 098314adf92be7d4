"""Property tests of every parser: random bytes, random rows and random calibration values may
only raise the project's typed errors (``SvainsError``), never anything else (issue 12); what a
reader accepts it returns unchanged (the values of the accepted text, and written data read back
bit for bit, issue 26).

Examples are few per property (``max_examples``) so the file stays fast.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svains.datasets import load_dataset
from svains.datasets.asl_reader import (
    read_features,
    read_gps,
    read_groundtruth,
    read_imu,
    read_mag,
    read_sonar,
)
from svains.datasets.asl_writer import AslWriter
from svains.datasets.kitti import read_kitti
from svains.datasets.trajectory import read_tum, write_tum
from svains.datasets.types import (
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
from svains.errors import DatasetError, SvainsError
from svains.sim.config import SimConfig

# Seeded in the suite, like every RNG here; SVAINS_HYPOTHESIS_EXAMPLES=400 explores afresh
# (run it after touching a parser).
_EXPLORE = os.environ.get("SVAINS_HYPOTHESIS_EXAMPLES")
FAST = settings(
    max_examples=int(_EXPLORE or 40), deadline=None, derandomize=_EXPLORE is None,
    suppress_health_check=[HealthCheck.too_slow],
)  # fmt: skip

T_BS = {"cols": 4, "rows": 4, "data": [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]}
GOOD_YAML: dict[str, dict[str, Any]] = {
    "imu0": {"T_BS": T_BS, "rate_hz": 200.0, "gyroscope_noise_density": 1.7e-4,
             "gyroscope_random_walk": 1.9e-5, "accelerometer_noise_density": 2e-3,
             "accelerometer_random_walk": 3e-3},
    "gps0": {"T_BS": T_BS, "rate_hz": 1.0, "position_noise_std": 1.0, "velocity_noise_std": 0.1},
    "mag0": {"T_BS": T_BS, "rate_hz": 10.0, "reference_field_W": [0.0, 0.2, -0.4],
             "noise_std": 0.01},
    "sonar0": {"T_BS": T_BS, "rate_hz": 20.0, "noise_std": 0.02, "ground_height": 0.0},
    "features0": {"T_BS": T_BS, "pixel_noise_std": 0.5},
    "state_groundtruth_estimate0": {"T_BS": T_BS},
}  # fmt: skip
READERS: dict[str, tuple[Callable[[Path], object], int]] = {
    "imu0": (read_imu, 7),
    "gps0": (read_gps, 7),
    "mag0": (read_mag, 4),
    "sonar0": (read_sonar, 2),
    "features0": (read_features, 6),
    "state_groundtruth_estimate0": (read_groundtruth, 17),
}

field_text = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "nan", "inf", "-0", "1e400", "0x10", "\uff11", "#", "a,b"]),
    st.text(max_size=6),
)
number_text = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.integers(min_value=-(2**60), max_value=2**60).map(str),
    st.floats(min_value=-1e3, max_value=1e3).map(lambda v: f" {v:.3e} "),
    st.sampled_from(["-0", "+1.5", "1_0", "\uff11", "1e-400", " 2 "]),
)
# Calibration values: anything, or a number a field may well accept.
calib_value = st.one_of(st.floats(min_value=1e-6, max_value=1e6), st.integers(1, 1000))
yaml_value = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5)),
    lambda inner: st.one_of(st.lists(inner, max_size=17), st.dictionaries(st.text(max_size=4),
                                                                           inner, max_size=3)),
    max_leaves=20,
)  # fmt: skip


def only_typed_errors(fn: Callable[..., object], *args: object) -> None:
    """Call ``fn``; a SvainsError is an acceptable answer to bad input, anything else fails."""
    with contextlib.suppress(SvainsError):
        fn(*args)


def accepted(fn: Callable[..., object], *args: object) -> object | None:
    """``fn(*args)``, or None when it refuses with a SvainsError (anything else fails)."""
    try:
        return fn(*args)
    except SvainsError:
        return None


def _columns(name: str, result: object) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps (N,) and the other columns (N, n_cols - 1), in file order, of a reader's
    result for stream ``name``."""
    if name == "features0":
        assert isinstance(result, FeatureStream)
        return result.t_ns, np.column_stack([result.track_id, result.uv_left, result.uv_right])
    if name == "state_groundtruth_estimate0":
        assert isinstance(result, GroundTruth)
        return result.t_ns, np.column_stack([result.p_W_B, result.q_W_B_wxyz, result.v_W_B,
                                             result.bg_B, result.ba_B])  # fmt: skip
    assert isinstance(result, tuple)
    s = result[0]
    cols = {"imu0": ("gyro_B", "accel_B"), "gps0": ("p_W_G", "v_W_G"), "mag0": ("m_S",),
            "sonar0": ("range_m",)}[name]  # fmt: skip
    return s.t_ns, np.column_stack([getattr(s, c) for c in cols])


def assert_reads_its_text(name: str, result: object, text: str) -> None:
    """What a stream reader accepted is the file's numbers: each row (blank and ``#`` lines
    skipped) split on commas, the first field as integer ns, the others as floats."""
    rows = [[f.strip() for f in ln.strip().split(",")] for ln in text.splitlines()
            if ln.strip() and not ln.strip().startswith("#")]  # fmt: skip
    t, v = _columns(name, result)
    assert t.tolist() == [int(r[0]) for r in rows]
    np.testing.assert_array_equal(v, np.array([[float(f) for f in r[1:]] for r in rows]))


# sensor.yaml key -> the calibration attribute it is read into (scalars).
CALIB_FIELDS = {
    "rate_hz": "rate_hz", "gyroscope_noise_density": "gyro_noise_density",
    "gyroscope_random_walk": "gyro_random_walk",
    "accelerometer_noise_density": "accel_noise_density",
    "accelerometer_random_walk": "accel_random_walk", "position_noise_std": "position_noise_std",
    "velocity_noise_std": "velocity_noise_std", "noise_std": "noise_std",
    "ground_height": "ground_height", "pixel_noise_std": "pixel_noise_std",
}  # fmt: skip


def assert_calibration_is_the_yaml(name: str, result: object, calib: dict[str, Any]) -> None:
    """An accepted sensor.yaml is read as written: every scalar key is its float, ``T_BS`` its
    16 numbers (the lever arm for gps0), ``reference_field_W`` its 3 numbers."""
    if name == "state_groundtruth_estimate0":
        return  # the ground-truth reader takes no calibration
    cal = result if name == "features0" else result[1]  # type: ignore[index]
    for key, value in calib.items():
        if key in CALIB_FIELDS:
            assert getattr(cal, CALIB_FIELDS[key]) == float(value), (key, value)
        elif key == "reference_field_W":
            np.testing.assert_array_equal(cal.m_W, [float(e) for e in value])
        elif key == "T_BS" and name != "features0":
            data = value.get("data") if isinstance(value, dict) else value
            T = np.array([float(e) for e in data]).reshape(4, 4)
            if name == "gps0":
                np.testing.assert_array_equal(cal.p_B_G, T[:3, 3])
            else:
                np.testing.assert_array_equal(cal.T_B_S, T)


def _stream(tmp: Path, name: str, data: bytes, calib: dict[str, Any] | None = None) -> Path:
    folder = tmp / name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "data.csv").write_bytes(data)
    text = "%YAML:1.0\n" + yaml.safe_dump(calib if calib is not None else GOOD_YAML[name])
    (folder / "sensor.yaml").write_text(text)
    return folder


@FAST
@given(name=st.sampled_from(sorted(READERS)), data=st.binary(max_size=300))
def test_stream_readers_on_random_bytes(name: str, data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        got = accepted(READERS[name][0], _stream(Path(d), name, data))
    if got is not None:
        assert_reads_its_text(name, got, data.decode("utf-8-sig"))


@FAST
@given(name=st.sampled_from(sorted(READERS)), data=st.data())
def test_stream_readers_on_random_rows(name: str, data: st.DataObject) -> None:
    n_cols = READERS[name][1]
    if data.draw(st.booleans()):  # well-formed rows (numbers in many spellings): mostly read
        t = np.cumsum(data.draw(st.lists(st.integers(20_000, 10**9), min_size=1, max_size=6)))
        rows = [[str(int(ti)), *data.draw(st.lists(number_text, min_size=n_cols - 1,
                                                   max_size=n_cols - 1))] for ti in t]  # fmt: skip
    else:
        widths = st.one_of(st.just(n_cols), st.integers(min_value=0, max_value=n_cols + 2))
        rows = data.draw(st.lists(widths.flatmap(lambda w: st.lists(field_text, min_size=w,
                                                                      max_size=w)), max_size=6))
    text = "#header\n" + "\n".join(",".join(r) for r in rows) + "\n"
    with tempfile.TemporaryDirectory() as d:
        got = accepted(READERS[name][0], _stream(Path(d), name, text.encode("utf-8")))
    if got is not None:
        assert_reads_its_text(name, got, text)


@FAST
@given(name=st.sampled_from(sorted(READERS)), data=st.data())
def test_stream_readers_on_random_calibration_values(name: str, data: st.DataObject) -> None:
    calib = dict(GOOD_YAML[name])
    for key in data.draw(st.lists(st.sampled_from(sorted(calib)), min_size=1, max_size=3)):
        calib[key] = data.draw(st.one_of(yaml_value, calib_value))
    n_cols = READERS[name][1]
    # 1 ms apart: a valid table (1 µs spacing was refused as "not nanoseconds" before any
    # calibration value was read).
    body = "\n".join(f"{10**6 * (k + 1)}," + ",".join(["1.0"] * (n_cols - 1)) for k in range(3))
    with tempfile.TemporaryDirectory() as d:
        got = accepted(READERS[name][0], _stream(Path(d), name, f"#h\n{body}\n".encode(), calib))
    if got is not None:
        assert_reads_its_text(name, got, body)
        assert_calibration_is_the_yaml(name, got, calib)


@FAST
@given(camera=st.dictionaries(
    st.sampled_from(["T_BS", "rate_hz", "resolution", "camera_model", "intrinsics",
                     "distortion_model", "distortion_coefficients"]), yaml_value, max_size=7),
    body=st.one_of(st.binary(max_size=80), yaml_value.map(lambda v: yaml.safe_dump(
        {"gravity_W": v}).encode())))  # fmt: skip
def test_load_dataset_on_random_camera_and_body_files(camera: dict[str, Any], body: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        mav0 = Path(d) / "mav0"
        for cam in ("cam0", "cam1"):
            (mav0 / cam).mkdir(parents=True)
            (mav0 / cam / "data.csv").write_text("#timestamp [ns],filename\n")
            (mav0 / cam / "sensor.yaml").write_text("%YAML:1.0\n" + yaml.safe_dump(camera))
        (mav0 / "body.yaml").write_bytes(body)
        only_typed_errors(load_dataset, Path(d))


@FAST
@given(cam_csv=st.binary(max_size=120), kinematics=st.binary(max_size=200),
       landmarks=st.binary(max_size=120))  # fmt: skip
def test_load_dataset_on_random_image_lists_and_simulator_extras(
    cam_csv: bytes, kinematics: bytes, landmarks: bytes
) -> None:
    with tempfile.TemporaryDirectory() as d:
        mav0 = Path(d) / "mav0"
        gt = _stream(mav0, "state_groundtruth_estimate0",
                     b"#h\n1000," + b"0," * 3 + b"1,0,0,0," + b"0," * 8 + b"0\n")  # fmt: skip
        (gt / "kinematics.csv").write_bytes(kinematics)
        (gt / "landmarks.csv").write_bytes(landmarks)
        (mav0 / "cam0").mkdir()
        (mav0 / "cam0" / "data.csv").write_bytes(cam_csv)
        (mav0 / "cam0" / "sensor.yaml").write_text(
            "%YAML:1.0\n" + yaml.safe_dump({"T_BS": T_BS, "resolution": [752, 480],
                                             "intrinsics": [458.0, 457.0, 367.0, 248.0]}))
        only_typed_errors(load_dataset, Path(d))


@FAST
@given(data=st.one_of(
    st.binary(max_size=200),
    st.lists(st.lists(field_text, min_size=8, max_size=8), max_size=5).map(
        lambda rows: "\n".join(" ".join(r) for r in rows).encode("utf-8")),
))  # fmt: skip
def test_tum_reader_on_random_input(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "t.tum").write_bytes(data)
        got = accepted(read_tum, Path(d) / "t.tum")
    if got is not None:  # then it is the file's numbers: t x y z qx qy qz qw
        rows = [ln.replace(",", " ").split() for ln in data.decode("utf-8-sig").splitlines()
                if ln.strip() and not ln.strip().startswith("#")]  # fmt: skip
        t, p, q = got  # type: ignore[misc]
        a = np.array([[float(f) for f in r[1:]] for r in rows])
        np.testing.assert_array_equal(p, a[:, :3])
        np.testing.assert_array_equal(q, a[:, [6, 3, 4, 5]])
        assert len(t) == len(rows)


@FAST
@given(calib=st.binary(max_size=200), times=st.lists(field_text, max_size=4),
       poses=st.binary(max_size=100))  # fmt: skip
def test_kitti_reader_on_random_input(calib: bytes, times: list[str], poses: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        (root / "calib.txt").write_bytes(calib)
        (root / "times.txt").write_text("\n".join(times) + "\n")
        (root / "poses.txt").write_bytes(poses)
        (root / "image_0").mkdir()
        only_typed_errors(read_kitti, root)


@FAST
@given(values=st.dictionaries(
    st.sampled_from(["duration_s", "seed", "gravity_W", "scenario", "imu", "gps", "camera"]),
    yaml_value, max_size=4))  # fmt: skip
def test_simulator_config_on_random_values(values: dict[str, Any]) -> None:
    def build() -> None:
        SimConfig.from_dict(values).validate()

    only_typed_errors(build)


# Valid values of every kind a writer may meet: any finite double (subnormals, -0.0, extremes).
FINITE = st.floats(allow_nan=False, allow_infinity=False)
POSITIVE = st.floats(min_value=1e-300, max_value=1e300)


def _draw_rows(data: st.DataObject, n: int, k: int, elements: Any = FINITE) -> np.ndarray:
    return np.array(data.draw(st.lists(elements, min_size=n * k, max_size=n * k))).reshape(n, k)


def _draw_unit_quaternions(data: st.DataObject, n: int) -> np.ndarray:
    q = _draw_rows(data, n, 4, st.floats(min_value=-1.0, max_value=1.0))
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(norm > 0.1, q / np.maximum(norm, 0.1), [1.0, 0.0, 0.0, 0.0])


def _draw_rigid(data: st.DataObject) -> np.ndarray:
    from svains.geometry.rotation import quat_to_rotmat

    T = np.eye(4)
    T[:3, :3] = quat_to_rotmat(_draw_unit_quaternions(data, 1)[0])
    T[:3, 3] = _draw_rows(data, 1, 3, st.floats(min_value=-1e6, max_value=1e6))[0]
    return T


def assert_same(read: object, written: object) -> None:
    """Arrays equal value for value (the sign of zero too), scalars equal."""
    a, b = np.asarray(read), np.asarray(written)
    np.testing.assert_array_equal(a, b)
    if a.dtype.kind == "f":
        np.testing.assert_array_equal(np.signbit(a), np.signbit(b))


@FAST
@given(data=st.data(), n=st.integers(min_value=3, max_value=6))
def test_written_streams_read_back_bit_for_bit(data: st.DataObject, n: int) -> None:
    """Round trip: every stream and calibration the writer writes is read back unchanged."""
    # Any start, or one of real recordings' size (1.4e18 ns: EuRoC), beyond float64's 2^53.
    t0 = data.draw(st.one_of(st.integers(0, 2**62), st.integers(10**18, 2 * 10**18)))
    steps = data.draw(st.lists(st.integers(20_000, 10**9), min_size=n - 1, max_size=n - 1))
    t = (t0 + np.concatenate([[0], np.cumsum(steps)])).astype(np.int64)
    imu = ImuStream(t, _draw_rows(data, n, 3), _draw_rows(data, n, 3))
    imu_cal = ImuCalib(_draw_rigid(data), *(data.draw(POSITIVE) for _ in range(5)))
    gps = GpsStream(t, _draw_rows(data, n, 3), _draw_rows(data, n, 3))
    gps_cal = GpsCalib(_draw_rigid(data)[:3, 3], *(data.draw(POSITIVE) for _ in range(3)))
    mag = MagStream(t, _draw_rows(data, n, 3))
    m_W = _draw_rows(data, 1, 3, st.floats(min_value=1e-100, max_value=1e100))[0]
    mag_cal = MagCalib(_draw_rigid(data), data.draw(POSITIVE), m_W, data.draw(POSITIVE))
    sonar = SonarStream(t, _draw_rows(data, n, 1)[:, 0])
    sonar_cal = SonarCalib(_draw_rigid(data), data.draw(POSITIVE), data.draw(POSITIVE),
                           data.draw(FINITE))  # fmt: skip
    ids = np.array(data.draw(st.lists(st.integers(-(2**53) + 1, 2**53 - 1), min_size=n,
                                      max_size=n)), dtype=np.int64)  # fmt: skip
    # frames no faster than a camera pair gives (``sensors.units.MAX_CAMERA_HZ``)
    t_frames = (t0 + np.concatenate([[0], np.cumsum(np.maximum(steps, 4_000_000))])).astype(
        np.int64)
    feats = FeatureStream(t_frames, ids, _draw_rows(data, n, 2), _draw_rows(data, n, 2),
                          data.draw(POSITIVE))  # fmt: skip
    gt = GroundTruth(t, _draw_rows(data, n, 3), _draw_unit_quaternions(data, n),
                     *(_draw_rows(data, n, 3) for _ in range(3)))  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        w = AslWriter(Path(d))
        got_imu, got_imu_cal = read_imu(w.write_imu(imu, imu_cal))
        got_gps, got_gps_cal = read_gps(w.write_gps(gps, gps_cal))
        got_mag, got_mag_cal = read_mag(w.write_mag(mag, mag_cal))
        got_sonar, got_sonar_cal = read_sonar(w.write_sonar(sonar, sonar_cal))
        got_feats = read_features(w.write_features(feats))
        got_gt = read_groundtruth(w.write_groundtruth(gt))
        tum = write_tum(Path(d) / "t.tum", t, gt.p_W_B, gt.q_W_B_wxyz)
        got_tum = read_tum(tum)
    for got, want in ((got_imu, imu), (got_imu_cal, imu_cal), (got_gps, gps),
                      (got_gps_cal, gps_cal), (got_mag, mag), (got_mag_cal, mag_cal),
                      (got_sonar, sonar), (got_sonar_cal, sonar_cal), (got_feats, feats),
                      (got_gt, gt)):  # fmt: skip
        for f in dataclasses.fields(want):
            assert_same(getattr(got, f.name), getattr(want, f.name))
    for a, b in zip(got_tum, (t, gt.p_W_B, gt.q_W_B_wxyz), strict=True):
        assert_same(a, b)


def test_property_helpers_fail_on_untyped_errors() -> None:
    # The helpers must let other exceptions through, or every property above is vacuous; a
    # typed error is the accepted answer to bad input; and the function does get called.
    def untyped() -> None:
        raise ValueError("x")

    def typed() -> None:
        raise DatasetError("bad row")

    for helper in (only_typed_errors, accepted):
        with pytest.raises(ValueError, match="x"):
            helper(untyped)
        assert helper(typed) is None
    calls: list[int] = []
    only_typed_errors(calls.append, 1)
    assert calls == [1]
    assert accepted(lambda v: 2 * v, 21) == 42


def test_a_large_table_is_read_by_numpy_alike_and_its_errors_keep_their_lines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Above FAST_TABLE_BYTES a numeric CSV goes through numpy's C reader (a 600 s features0:
    9.3 s and 0.96 GB before, 3.3 s and 0.23 GB now): the same arrays bit for bit as the
    careful reader, and a bad row still named by its line, found by the careful reader or
    counted for the error alone."""
    from svains.datasets import _textio
    from svains.errors import DatasetError

    rng = np.random.default_rng(9)
    n = 30_000
    t = 1_403_715_273_262_142_976 + np.arange(n, dtype=np.int64) * 5_000_000
    a = rng.normal(size=(n, 6)) * [1, 1, 1, 9, 9, 9]
    rows = [f"{ti},{','.join(repr(float(v)) for v in r)}" for ti, r in zip(t, a, strict=True)]
    path = tmp_path / "data.csv"
    header = "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n\n"  # and a blank line: row k on line k+3
    path.write_text(header + "\n".join(rows) + "\n")
    assert path.stat().st_size > _textio.FAST_TABLE_BYTES
    fast_t, fast_a, lines = _textio.read_numeric_table(path, 7)
    assert isinstance(lines, _textio.DataLines)  # numpy read it: no list of line numbers made
    monkeypatch.setattr(_textio, "FAST_TABLE_BYTES", 1 << 60)
    slow_t, slow_a, _ = _textio.read_numeric_table(path, 7)
    np.testing.assert_array_equal(fast_t, slow_t)
    np.testing.assert_array_equal(fast_a, slow_a)
    assert lines[0] == 3 and lines[n - 1] == n + 2
    monkeypatch.undo()
    bad = list(rows)
    bad[20_000] = f"{t[20_000]},nan,{','.join(repr(float(v)) for v in a[20_000][1:])}"
    path.write_text(header + "\n".join(bad) + "\n")
    with pytest.raises(DatasetError, match=r"data\.csv:20003: NaN or infinite value"):
        _textio.read_numeric_table(path, 7)
    late = list(rows)
    late[25_000] = f"{t[24_000]},{','.join(repr(float(v)) for v in a[25_000])}"
    path.write_text(header + "\n".join(late) + "\n")
    with pytest.raises(DatasetError, match=rf"data\.csv:25003: non-increasing timestamp "
                       rf"{t[24_000]} after {t[24_999]}"):  # fmt: skip
        _textio.read_numeric_table(path, 7)
