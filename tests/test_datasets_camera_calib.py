"""Camera sensor.yaml: 5-coefficient radial-tangential, equidistant fisheye, timeshift_cam_imu."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset, stereo_pairs
from svains.errors import CalibrationError
from test_datasets_roundtrip import write_full


def _append(path: Path, text: str) -> None:
    path.write_text(path.read_text() + text)


def _set_distortion(path: Path, model: str, coeffs: str) -> None:
    lines = [
        ln for ln in path.read_text().splitlines()
        if not ln.startswith(("distortion_model", "distortion_coefficients"))
    ]  # fmt: skip
    lines += [f"distortion_model: {model}", f"distortion_coefficients: {coeffs}"]
    path.write_text("\n".join(lines) + "\n")


def test_timeshift_moves_image_stamps_once(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_full(root)
    before = load_dataset(root)
    assert before.left is not None and before.cam0 is not None
    assert before.cam0.timeshift_cam_imu_s == 0.0
    for cam in ("cam0", "cam1"):
        _append(root / "mav0" / cam / "sensor.yaml", "timeshift_cam_imu: -0.0123456789\n")
    after = load_dataset(root)
    assert after.left is not None and after.right is not None and after.cam0 is not None
    assert after.cam0.timeshift_cam_imu_s == pytest.approx(-0.0123456789)
    # t_imu = t_cam + timeshift, rounded to the nanosecond; the IMU stays where it was.
    np.testing.assert_array_equal(after.left.t_ns, before.left.t_ns - 12_345_679)
    np.testing.assert_array_equal(after.right.t_ns, before.right.t_ns - 12_345_679)
    assert after.imu is not None and before.imu is not None
    np.testing.assert_array_equal(after.imu.t_ns, before.imu.t_ns)
    # Pairs keep matching (both cameras moved together) and carry the shifted stamps.
    np.testing.assert_array_equal(stereo_pairs(after)[0], stereo_pairs(before)[0] - 12_345_679)


def test_bad_timeshift_is_rejected(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_full(root)
    _append(root / "mav0" / "cam0" / "sensor.yaml", "timeshift_cam_imu: soon\n")
    with pytest.raises(CalibrationError, match=r"cam0/sensor\.yaml: field 'timeshift_cam_imu'"):
        load_dataset(root)


def test_five_and_fisheye_coefficients_are_read(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_full(root)
    _set_distortion(root / "mav0" / "cam0" / "sensor.yaml", "radial-tangential",
                    "[-0.37, 0.2, 0.002, 0.001, -0.07]")
    _set_distortion(root / "mav0" / "cam1" / "sensor.yaml", "equidistant",
                    "[0.01, -0.02, 0.003, -0.0004]")
    ds = load_dataset(root)
    assert ds.cam0 is not None and ds.cam1 is not None
    np.testing.assert_array_equal(ds.cam0.distortion, [-0.37, 0.2, 0.002, 0.001, -0.07])
    assert ds.cam1.distortion_model == "equidistant"
    np.testing.assert_array_equal(ds.cam1.distortion, [0.01, -0.02, 0.003, -0.0004])


@pytest.mark.parametrize(
    ("model", "coeffs", "message"),
    [
        ("radial-tangential", "[0.1, 0.2, 0.3]", "radtan distortion needs 4 or 5 coefficients"),
        ("equidistant", "[0.1, 0.2, 0.3, 0.4, 0.5]", "equidistant distortion needs 4 coeff"),
        ("double-sphere", "[0.1, 0.2]", "distortion model 'double-sphere' is not supported"),
    ],
)
def test_bad_distortion_is_rejected(tmp_path: Path, model: str, coeffs: str, message: str) -> None:
    root = tmp_path / "ds"
    write_full(root)
    _set_distortion(root / "mav0" / "cam1" / "sensor.yaml", model, coeffs)
    with pytest.raises(CalibrationError, match=f"cam1/sensor.yaml: {message}"):
        load_dataset(root)


def test_a_camera_without_distortion_coefficients_is_read_undistorted_and_warned(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    """A user's probe (2026-12-06): the field left out was read as no distortion silently."""
    root = tmp_path / "ds"
    write_full(root)
    path = root / "mav0" / "cam0" / "sensor.yaml"
    path.write_text("\n".join(ln for ln in path.read_text().splitlines()
                              if not ln.startswith("distortion_coefficients")) + "\n")
    with caplog.at_level("WARNING", logger="svains.datasets.asl_reader"):
        ds = load_dataset(root)
    assert ds.cam0 is not None and not ds.cam0.distortion.any()
    assert "cam0/sensor.yaml: no 'distortion_coefficients': the lens is taken as undistorted" \
        in caplog.text


def test_kalibr_s_name_for_the_distortion_coefficients_is_read(tmp_path: Path) -> None:
    """A sensor.yaml written from a Kalibr camchain names them ``distortion_coeffs``: the lens
    was read as undistorted under a warning (a user's probe)."""
    root = tmp_path / "ds"
    write_full(root)
    path = root / "mav0" / "cam0" / "sensor.yaml"
    path.write_text("\n".join(
        "distortion_coeffs: [-0.28, 0.07, 0.0002, 0.00002]"
        if ln.startswith("distortion_coefficients") else ln
        for ln in path.read_text().splitlines()) + "\n")  # fmt: skip
    ds = load_dataset(root)
    assert ds.cam0 is not None
    np.testing.assert_allclose(ds.cam0.distortion, [-0.28, 0.07, 0.0002, 0.00002])


def test_a_nested_4x4_t_bs_is_read(tmp_path: Path) -> None:
    """``T_BS`` as a nested 4x4 list (Kalibr's camchain form) was refused as "must be 16
    numbers" though no ``data`` key was given (a user's probe)."""
    from svains.datasets._textio import yaml_T_BS

    T = [[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    np.testing.assert_array_equal(yaml_T_BS({"T_BS": T}, tmp_path / "sensor.yaml"), np.array(T))
    flat = [e for r in T for e in r]
    np.testing.assert_array_equal(
        yaml_T_BS({"T_BS": {"rows": 4, "cols": 4, "data": flat}}, tmp_path), np.array(T))
