"""Kalibr camchain-imucam.yaml / imu.yaml: the EuRoC calibration written as Kalibr files gives
the same cameras, IMU noise and stereo rectification as EuRoC's own sensor.yaml files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _kalibr_files import write_euroc_kalibr
from svains.datasets import load_dataset
from svains.datasets.kalibr import apply_kalibr, read_camchain, read_kalibr_imu, write_camchain
from svains.errors import CalibrationError, DatasetError
from svains.frontend.rectify import StereoRectifier


@pytest.fixture(scope="module")
def euroc(euroc_micro: Path):  # type: ignore[no-untyped-def]
    return load_dataset(euroc_micro)


def test_camchain_from_euroc_gives_the_same_rectification(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    chain, imu = write_euroc_kalibr(euroc, tmp_path)
    ds = apply_kalibr(euroc, chain, imu)
    for ours, theirs in ((ds.cam0, euroc.cam0), (ds.cam1, euroc.cam1)):
        np.testing.assert_allclose(ours.T_B_C, theirs.T_B_C, atol=1e-12)
        np.testing.assert_array_equal(ours.intrinsics, theirs.intrinsics)
        np.testing.assert_array_equal(ours.distortion, theirs.distortion)
        assert ours.distortion_model == "radtan" and ours.rate_hz == theirs.rate_hz
    a = StereoRectifier.from_calibration(euroc.cam0, euroc.cam1)
    b = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    assert not a.identity
    assert b.rig.f == pytest.approx(a.rig.f, abs=1e-9)
    assert b.rig.baseline == pytest.approx(a.rig.baseline, abs=1e-12)
    np.testing.assert_allclose(b.rig.R_B_C, a.rig.R_B_C, atol=1e-12)
    np.testing.assert_allclose(b.P1, a.P1, atol=1e-9)
    np.testing.assert_allclose(b.P2, a.P2, atol=1e-9)
    np.testing.assert_allclose(b.xymap_left, a.xymap_left, atol=1e-3)
    np.testing.assert_allclose(b.xymap_right, a.xymap_right, atol=1e-3)
    i = euroc.imu_calib
    assert ds.imu_calib.gyro_noise_density == i.gyro_noise_density
    assert ds.imu_calib.accel_random_walk == i.accel_random_walk
    assert ds.imu_calib.rate_hz == i.rate_hz


def test_openvins_T_imu_cam_and_chained_T_cn_cnm1_match_T_cam_imu(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    kal = read_camchain(write_euroc_kalibr(euroc, tmp_path)[0])
    ov = read_camchain(
        write_camchain(tmp_path / "ov.yaml", [euroc.cam0, euroc.cam1], openvins=True)
    )
    np.testing.assert_allclose(ov.cameras[1].T_B_C, kal.cameras[1].T_B_C, atol=1e-12)
    # cam1 with only T_cn_cnm1 is chained onto cam0.
    text = (tmp_path / "camchain-imucam.yaml").read_text()
    head, cam1 = text.split("cam1:\n")
    rows = cam1.split("  T_cn_cnm1:\n")[1]
    chained = head + "cam1:\n  T_cn_cnm1:\n" + rows
    (tmp_path / "chained.yaml").write_text(chained)
    ch = read_camchain(tmp_path / "chained.yaml")
    np.testing.assert_allclose(ch.cameras[1].T_B_C, kal.cameras[1].T_B_C, atol=1e-12)


def test_equidistant_and_five_coefficient_radtan_parse(tmp_path: Path) -> None:
    p = tmp_path / "camchain.yaml"
    p.write_text(
        "cam0:\n  camera_model: pinhole\n  distortion_model: equidistant\n"
        "  distortion_coeffs: [0.0034, 0.0007, -0.0020, 0.0002]\n"
        "  intrinsics: [190.97, 190.97, 254.93, 256.89]\n  resolution: [512, 512]\n"
        "  timeshift_cam_imu: 0.0125\n  rostopic: /cam0/image_raw\n"
        "cam1:\n  T_cn_cnm1:\n  - [1, 0, 0, -0.1]\n  - [0, 1, 0, 0]\n  - [0, 0, 1, 0]\n"
        "  - [0, 0, 0, 1]\n  camera_model: pinhole\n  distortion_model: radtan\n"
        "  distortion_coeffs: [-0.1, 0.01, 0.001, 0.002, 0.0003]\n"
        "  intrinsics: [190.0, 190.0, 250.0, 250.0]\n  resolution: [512, 512]\n"
    )
    ch = read_camchain(p)
    c0, c1 = ch.cameras
    assert c0.distortion_model == "equidistant" and c0.distortion.shape == (4,)
    assert c1.distortion_model == "radtan" and c1.distortion.shape == (5,)
    assert ch.timeshift_cam_imu_s == 0.0125 and ch.rostopics == ("/cam0/image_raw", None)
    np.testing.assert_allclose(c1.T_B_C[:3, 3], [0.1, 0.0, 0.0])  # cam1 is right of cam0


def test_timeshift_moves_image_times(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    chain = write_camchain(
        tmp_path / "c.yaml", [euroc.cam0, euroc.cam1], timeshift_cam_imu_s=-0.0025
    )
    ds = apply_kalibr(euroc, chain, None)
    np.testing.assert_array_equal(ds.left.t_ns, euroc.left.t_ns - 2_500_000)
    np.testing.assert_array_equal(ds.right.t_ns, euroc.right.t_ns - 2_500_000)
    assert ds.extras["timeshift_cam_imu_ns"] == -2_500_000
    np.testing.assert_array_equal(euroc.left.t_ns[:1], load_dataset(euroc.root).left.t_ns[:1])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("cam0:\n  camera_model: omni\n  intrinsics: [1, 1, 1, 1]\n  resolution: [4, 4]\n",
         "camera_model 'omni' is not supported"),
        ("cam0:\n  distortion_model: fov\n  intrinsics: [1, 1, 1, 1]\n  resolution: [4, 4]\n",
         "distortion_model 'fov' is not supported"),
        ("cam0:\n  distortion_model: equidistant\n  distortion_coeffs: [1, 2]\n"
         "  intrinsics: [1, 1, 1, 1]\n  resolution: [4, 4]\n", "needs 4 distortion_coeffs, has 2"),
        ("cam0:\n  T_cam_imu: [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
         "  intrinsics: [1, 1, 1, 1]\n  resolution: [4, 4]\n", "rotation is not orthonormal"),
        ("cam0:\n  resolution: [4, 4]\n", "cam0 has no 'intrinsics'"),
        ("imu0: 3\n", "no camera entries"),
    ],
)  # fmt: skip
def test_bad_camchain_is_refused_with_its_reason(tmp_path: Path, text: str, message: str) -> None:
    p = tmp_path / "camchain.yaml"
    p.write_text(text)
    with pytest.raises(CalibrationError, match=message):
        read_camchain(p)


def test_imu_yaml_nested_under_imu0_and_bad_noise(tmp_path: Path) -> None:
    p = tmp_path / "imu.yaml"
    p.write_text(
        "imu0:\n  accelerometer_noise_density: 0.002\n  accelerometer_random_walk: 0.003\n"
        "  gyroscope_noise_density: 0.00017\n  gyroscope_random_walk: 0.00002\n"
        "  rostopic: /imu0\n  update_rate: 200.0\n"
    )
    cal, topic = read_kalibr_imu(p)
    assert (cal.accel_noise_density, cal.gyro_random_walk, cal.rate_hz) == (0.002, 0.00002, 200.0)
    assert topic == "/imu0"
    p.write_text("gyroscope_noise_density: 0.1\n")
    with pytest.raises(CalibrationError, match="missing field 'gyroscope_random_walk'"):
        read_kalibr_imu(p)


def test_a_camchain_of_another_resolution_is_refused_on_load(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A camchain for 1392x512 images over EuRoC's 752x480 ones: every pair was dropped one by
    one during the run, then exit 1 (a user's probe); refused on load as a sensor.yaml's is."""
    from dataclasses import replace

    other = [replace(c, resolution=(1392, 512)) for c in (euroc.cam0, euroc.cam1)]
    chain = write_camchain(tmp_path / "chain.yaml", tuple(other), euroc.imu_calib.T_B_S, 0.0)
    with pytest.raises(CalibrationError, match=r"cam0/data/\d+\.png: image is 752x480 px but "
                       r".*chain\.yaml field 'resolution' says 1392x512"):  # fmt: skip
        apply_kalibr(euroc, chain)


def test_a_recording_without_an_imu_calibration_is_warned_before_the_run(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A bag with a camchain and no imu.yaml ran on another IMU's noise densities without a
    word (a simulated bag: ATE 4.8 m against 0.06 m with its own, a user's probe)."""
    from contextlib import suppress
    from dataclasses import replace

    from svains.errors import SvainsError
    from svains.navigation.options import InitOptions, RunConfig
    from svains.replay import replay, resolve_config
    from test_datasets_roundtrip import write_full

    write_full(tmp_path / "ds")
    ds = replace(load_dataset(tmp_path / "ds"), imu_calib=None)
    # whatever the random streams give after it
    with caplog.at_level("WARNING", logger="svains.replay.replay"), suppress(SvainsError):
        replay(ds, resolve_config(ds, RunConfig(init=InitOptions(mode="groundtruth"))))
    assert ("no IMU calibration, so EuRoC's ADIS16448 noise densities and an IMU at the body "
            "origin are assumed: give the IMU's Kalibr imu.yaml (--imu-calib)") in caplog.text


def test_the_front_end_takes_a_camchain_too(euroc, euroc_micro: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``svains frontend`` had no --calib, though a bag without one told the user to pass it
    (a user's probe): the same frames as with the data set's own calibration."""
    import json

    from typer.testing import CliRunner

    from svains.cli.main import app

    chain, _ = write_euroc_kalibr(euroc, tmp_path)
    runner = CliRunner()
    for name, extra in (("own", []), ("kalibr", ["--calib", str(chain)])):
        res = runner.invoke(app, ["frontend", str(euroc_micro), "--out", str(tmp_path / name),
                                  *extra])  # fmt: skip
        assert res.exit_code == 0, res.output
    own, kal = (json.loads((tmp_path / n / "report.json").read_text()) for n in ("own", "kalibr"))
    assert kal["frames"] == own["frames"] > 50


def test_radtan_coefficients_under_an_equidistant_name_are_warned(
    euroc, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:  # type: ignore[no-untyped-def]
    """A camchain saying ``equidistant`` over radial-tangential coefficients (a Kalibr slip:
    KITTI raw ran to 1.79 m instead of 0.28 m with only bias and GPS warnings, a user's probe)
    is warned; real fisheye coefficients (small) and a rectilinear lens fitted as equidistant
    (k1 near +1/3) are not."""
    from dataclasses import replace

    cams = (euroc.cam0, euroc.cam1)
    slip = tuple(replace(c, distortion_model="equidistant") for c in cams)
    fisheye = tuple(replace(c, distortion_model="equidistant",
                            distortion=np.array([0.0034, 0.0007, -0.0020, 0.0002]))
                    for c in cams)  # fmt: skip
    rectilinear = tuple(replace(c, distortion_model="equidistant",
                                distortion=np.array([0.33, 0.13, 0.05, 0.02])) for c in cams)
    with caplog.at_level("WARNING", logger="svains.datasets.validate"):
        for i, chain in enumerate((fisheye, rectilinear)):
            read_camchain(write_camchain(tmp_path / f"ok{i}.yaml", chain,
                                         euroc.imu_calib.T_B_S, 0.0))  # fmt: skip
        assert "look like radial-tangential" not in caplog.text
        read_camchain(write_camchain(tmp_path / "slip.yaml", slip, euroc.imu_calib.T_B_S, 0.0))
    assert caplog.text.count("equidistant (fisheye) coefficients") == 2
    assert "cam0's equidistant (fisheye) coefficients [-2.8341e-01" in caplog.text


def _edited_chain(euroc, tmp_path: Path, edit) -> Path:  # type: ignore[no-untyped-def]
    """The EuRoC camchain with the text ``edit``-ed (a function of the file's text)."""
    chain, _ = write_euroc_kalibr(euroc, tmp_path)
    chain.write_text(edit(chain.read_text()))
    return chain


def test_a_rounded_rotation_is_made_a_rotation_and_said(
    euroc, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:  # type: ignore[no-untyped-def]
    """Rounded to 3 decimals (|R^T R - I| near 1e-3) a rotation was used as it was (EuRoC from
    synthetic features 0.0099 -> 0.0359 m, NEES 56; a user's probe): now the nearest rotation,
    warned with the size; the Kalibr reader and sensor.yaml share one tolerance."""
    import re

    def rounded(text: str) -> str:
        return re.sub(r"-?\d+\.\d+(e-?\d+)?", lambda m: f"{float(m.group(0)):.3f}", text)

    chain = _edited_chain(euroc, tmp_path, rounded)
    with caplog.at_level("WARNING"):
        ch = read_camchain(chain)
    assert "rotation is not orthonormal (|R^T R - I| = " in caplog.text
    assert "the nearest rotation is used" in caplog.text
    for c in ch.cameras:
        R = c.T_B_C[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R, euroc.cam0.T_B_C[:3, :3] if c.name == "cam0"
                                   else euroc.cam1.T_B_C[:3, :3], atol=2e-3)  # fmt: skip
    # a rotation off by 1e-2 is refused with its size
    p = tmp_path / "bad.yaml"
    p.write_text("cam0:\n  T_cam_imu: [[1.01, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
                 "  intrinsics: [1, 1, 1, 1]\n  resolution: [4, 4]\n")  # fmt: skip
    with pytest.raises(CalibrationError, match=r"not orthonormal \(\|R\^T R - I\| = 0\.0201 > "):
        read_camchain(p)


def test_a_timeshift_in_milliseconds_written_as_seconds_is_refused(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    chain = _edited_chain(euroc, tmp_path, lambda t: t.replace(
        "timeshift_cam_imu: 0", "timeshift_cam_imu: 20", 1))
    with pytest.raises(CalibrationError, match=r"cam0.timeshift_cam_imu' is 20 s, more than 1 s: "
                       "milliseconds written as seconds"):  # fmt: skip
        read_camchain(chain)


def test_a_camera_only_camchain_is_placed_through_the_data_sets_cam0(
    euroc, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:  # type: ignore[no-untyped-def]
    """Kalibr's camera-only camchain.yaml (no T_cam_imu) put cam0 at the IMU with no rotation,
    silently (a rig turned 90° against the IMU: 210 m from images; a user's probe)."""
    p, _ = write_euroc_kalibr(euroc, tmp_path)
    kept, skip = [], 0
    for ln in p.read_text().splitlines():  # drop each T_cam_imu and its four rows
        if ln.strip() == "T_cam_imu:":
            skip = 4
        elif skip:
            skip -= 1
        else:
            kept.append(ln)
    p.write_text("\n".join(kept) + "\n")
    text = p.read_text()
    assert "T_cam_imu" not in text and "T_cn_cnm1" in text
    with caplog.at_level("WARNING"):
        ds = apply_kalibr(euroc, p, None)
    assert "no camera-IMU transform (T_cam_imu; a camera-only camchain)" in caplog.text
    np.testing.assert_allclose(ds.cam0.T_B_C, euroc.cam0.T_B_C, atol=1e-9)
    np.testing.assert_allclose(ds.cam1.T_B_C, euroc.cam1.T_B_C, atol=1e-6)


def test_extrinsics_in_millimetres_are_refused_through_a_camchain(euroc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The same baseline check as a sensor.yaml's (it ran 452 m off from images)."""
    mm = [c.__class__(**{**c.__dict__, "T_B_C": np.block([[c.T_B_C[:3, :3], 1000 * c.T_B_C[:3, 3:]],
                                                          [np.zeros((1, 3)), np.ones((1, 1))]])})
          for c in (euroc.cam0, euroc.cam1)]  # fmt: skip
    p = write_camchain(tmp_path / "mm.yaml", mm, T_B_I=euroc.imu_calib.T_B_S)
    with pytest.raises(CalibrationError, match=r"baseline of 110\.\d m, expected < 20 m"):
        apply_kalibr(euroc, p, None)


def test_cameras_of_two_resolutions_are_refused_on_load(euroc) -> None:  # type: ignore[no-untyped-def]
    """One rectification maps one size: a smaller cam1 (its intrinsics scaled to it) had every
    pair dropped one by one, the message quoting cam0's size (a user's probe)."""
    import dataclasses

    from svains.datasets.validate import check_stereo_rig

    small = dataclasses.replace(euroc.cam1, resolution=(640, 400),
                                intrinsics=np.asarray(euroc.cam1.intrinsics) * (640 / 752))
    check_stereo_rig(euroc.cam0, euroc.cam1, Path("c0"), Path("c1"))
    with pytest.raises(CalibrationError, match=r"cam0 is 752x480 px and cam1 640x400 px: svains "
                       r"rectifies a pair of one size"):  # fmt: skip
        check_stereo_rig(euroc.cam0, small, Path("c0"), Path("c1"))


def test_a_folder_without_sensor_yaml_takes_its_calibration_from_kalibr(
    euroc, euroc_micro: Path, tmp_path: Path  # type: ignore[no-untyped-def]
) -> None:
    """Tables and images alone, the calibration a Kalibr pair (the own-sensor page's promise:
    a user's probe found the folder's own calibration demanded first); without the pair the
    missing sensor.yaml is still an error naming it."""
    chain, imu = write_euroc_kalibr(euroc, tmp_path / "kalibr")
    bare = tmp_path / "bare" / "mav0"
    for name in ("cam0", "cam1", "imu0"):
        (bare / name).mkdir(parents=True)
        (bare / name / "data.csv").symlink_to(euroc_micro / "mav0" / name / "data.csv")
    for name in ("cam0", "cam1"):
        (bare / name / "data").symlink_to(euroc_micro / "mav0" / name / "data")
    ds = load_dataset(bare.parent, calib=chain, imu_calib=imu)
    full = apply_kalibr(euroc, chain, imu)
    assert ds.cam0 is not None and ds.cam1 is not None and ds.imu_calib is not None
    np.testing.assert_array_equal(ds.left.t_ns, full.left.t_ns)
    np.testing.assert_allclose(ds.cam0.T_B_C, full.cam0.T_B_C, atol=1e-12)
    np.testing.assert_allclose(ds.cam1.T_B_C, full.cam1.T_B_C, atol=1e-12)
    assert ds.imu_calib.gyro_noise_density == full.imu_calib.gyro_noise_density
    with pytest.raises(DatasetError, match=r"missing file: .*imu0/sensor.yaml \(the IMU's "
                       r"calibration; or give a Kalibr imu.yaml: --imu-calib\)"):
        load_dataset(bare.parent, calib=chain)  # the IMU's calibration from nowhere
    # cam0's own sensor.yaml with a 5 ms offset, cam1's absent: both streams end on the
    # camchain's clock (the right one was moved by cam0's offset too, 5 ms from its pair).
    (bare / "cam0" / "sensor.yaml").write_text(
        (euroc_micro / "mav0" / "cam0" / "sensor.yaml").read_text()
        + "\ntimeshift_cam_imu: 0.005\n")  # fmt: skip
    half = load_dataset(bare.parent, calib=chain, imu_calib=imu)
    np.testing.assert_array_equal(half.left.t_ns, full.left.t_ns)
    np.testing.assert_array_equal(half.right.t_ns, full.right.t_ns)


def test_a_camchain_at_odds_with_itself_is_warned(
    euroc, tmp_path: Path, caplog: pytest.LogCaptureFixture  # type: ignore[no-untyped-def]
) -> None:
    """cam1's T_cam_imu (used) and its T_cn_cnm1, and cam1's timeshift against cam0's, were
    never compared: a camchain half edited by hand ran on one of them without a word."""
    chain, _ = write_euroc_kalibr(euroc, tmp_path / "k")
    text = chain.read_text()
    with caplog.at_level("WARNING", logger="svains.datasets.kalibr"):
        read_camchain(chain)
    assert caplog.records == []  # Kalibr's own: both agree
    lines = text.splitlines()
    at = lines.index("  T_cn_cnm1:") + 1  # cam1's first row: its x translation 5 mm more
    row = lines[at].rstrip("]").split(", ")
    row[-1] = repr(float(row[-1]) - 0.005)
    lines[at] = ", ".join(row) + "]"
    lines[-1] = "  timeshift_cam_imu: 0.004"  # cam1's, 4 ms against cam0's 0
    odd = tmp_path / "odd.yaml"
    odd.write_text("\n".join(lines) + "\n")
    with caplog.at_level("WARNING", logger="svains.datasets.kalibr"):
        got = read_camchain(odd)
    msgs = [r.getMessage() for r in caplog.records]
    assert any("cam1's T_cam_imu and its T_cn_cnm1 disagree by 0.00° and 5.0 mm: T_cam_imu is "
               "used" in m for m in msgs), msgs
    assert any("cam1.timeshift_cam_imu 4.00 ms differs from cam0's 0.00 ms" in m for m in msgs)
    np.testing.assert_allclose(got.cameras[1].T_B_C, read_camchain(chain).cameras[1].T_B_C)
