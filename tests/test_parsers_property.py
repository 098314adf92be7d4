"""Property tests of every parser: random bytes, random rows and random calibration values may
only raise the project's typed errors (``SvainsError``), never anything else (issue 12).

Examples are few per property (``max_examples``) so the file stays fast.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
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
from svains.datasets.kitti import read_kitti
from svains.datasets.trajectory import read_tum
from svains.errors import SvainsError
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
        only_typed_errors(READERS[name][0], _stream(Path(d), name, data))


@FAST
@given(name=st.sampled_from(sorted(READERS)), data=st.data())
def test_stream_readers_on_random_rows(name: str, data: st.DataObject) -> None:
    n_cols = READERS[name][1]
    widths = st.one_of(st.just(n_cols), st.integers(min_value=0, max_value=n_cols + 2))
    rows = data.draw(st.lists(widths.flatmap(lambda w: st.lists(field_text, min_size=w,
                                                                  max_size=w)), max_size=6))
    text = "#header\n" + "\n".join(",".join(r) for r in rows) + "\n"
    with tempfile.TemporaryDirectory() as d:
        only_typed_errors(READERS[name][0], _stream(Path(d), name, text.encode("utf-8")))


@FAST
@given(name=st.sampled_from(sorted(READERS)), data=st.data())
def test_stream_readers_on_random_calibration_values(name: str, data: st.DataObject) -> None:
    calib = dict(GOOD_YAML[name])
    for key in data.draw(st.lists(st.sampled_from(sorted(calib)), min_size=1, max_size=3)):
        calib[key] = data.draw(yaml_value)
    n_cols = READERS[name][1]
    body = "\n".join(f"{1000 * (k + 1)}," + ",".join(["1.0"] * (n_cols - 1)) for k in range(3))
    with tempfile.TemporaryDirectory() as d:
        only_typed_errors(READERS[name][0], _stream(Path(d), name, f"#h\n{body}\n".encode(),
                                                    calib))  # fmt: skip


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
        only_typed_errors(read_tum, Path(d) / "t.tum")


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


def test_property_helpers_fail_on_untyped_errors() -> None:
    # The helper itself must let other exceptions through, or every property above is vacuous.
    def untyped() -> None:
        raise ValueError("x")

    try:
        only_typed_errors(untyped)
    except ValueError:
        pass
    else:
        raise AssertionError("only_typed_errors swallowed a ValueError")
    assert math.isfinite(float(np.float64(1.0)))
