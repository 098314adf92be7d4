"""The online check of the GPS frame and the gyro's unit (``navigation.course_check``): the same
figures and verdicts as the load-time test on the same data, fix by fix; warned once in a run
fed past the readers' checks."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.types import GpsStream, ImuStream
from svains.datasets.validate import gps_course_vs_imu_turn
from svains.evaluation.run import run_method
from svains.navigation.course_check import CourseCheck
from svains.navigation.imu_history import ImuHistory
from svains.navigation.options import InitOptions, RunOptions
from test_datasets_units import G_W, _drive

NED = np.diag([1.0, 1.0, -1.0])[[1, 0, 2]]  # ENU -> north, east, down


def _online(t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, tg: np.ndarray,
            v: np.ndarray) -> CourseCheck:  # fmt: skip
    """Samples and fixes fed in time order, as the estimator does (each fix once the samples up
    to it are in)."""
    history = ImuHistory()
    check = CourseCheck(history, G_W)
    k = 0
    for t_fix, v_fix in zip(tg, v, strict=True):
        while k < t_ns.size and t_ns[k] <= t_fix:
            history.append(int(t_ns[k]), gyro[k], accel[k])
            k += 1
        check.observe_fix(int(t_fix), v_fix)
    return check


@pytest.fixture(scope="module")
def weaving() -> tuple[np.ndarray, ...]:
    t = np.arange(0.0, 40.0, 0.01)
    return _drive(0.3 * np.sin(2 * np.pi * t / 12.0), t)


def test_online_figures_match_the_load_time_test(weaving: tuple[np.ndarray, ...]) -> None:
    t_ns, gyro, accel, tg, v = weaving
    # the load-time test's 1 s grid stops short of the last fix: the same steps without it
    check = _online(t_ns, gyro, accel, tg[:-1], v[:-1])
    cosine, n, turn_deg, ratio = check.figures()  # type: ignore[misc]
    c0, n0, turn0, ratio0 = gps_course_vs_imu_turn(t_ns, gyro, accel, tg, v, G_W)  # type: ignore[misc]
    assert n == n0 and cosine == pytest.approx(c0, abs=2e-3)
    assert turn_deg == pytest.approx(turn0, rel=0.02) and ratio == pytest.approx(ratio0, rel=0.02)
    assert cosine > 0.99 and abs(ratio - 1.0) < 0.05 and check.warned == {}


def test_a_mirrored_gps_and_a_gyro_in_deg_s_are_warned_once(
    weaving: tuple[np.ndarray, ...], caplog: pytest.LogCaptureFixture
) -> None:
    t_ns, gyro, accel, tg, v = weaving
    with caplog.at_level(logging.WARNING, logger="svains.navigation.course_check"):
        ned = _online(t_ns, gyro, accel, tg, v @ NED.T)
        deg = _online(t_ns, np.degrees(gyro), accel, tg, v)
    assert sorted(ned.warned) == ["gps"] and sorted(deg.warned) == ["gyro"]
    assert caplog.text.count("online input: the GPS course turns against the IMU") == 1
    assert caplog.text.count("is it in deg/s?") == 1
    assert ned.summary()["warned"] == ["gps"] and ned.summary()["cosine"] < -0.99  # type: ignore[operator]


def test_steps_need_motion_and_the_samples_of_their_interval(
    weaving: tuple[np.ndarray, ...]
) -> None:
    t_ns, gyro, accel, tg, v = weaving
    assert _online(t_ns, gyro, accel, tg, 0.1 * v).steps == 0  # 0.8 m/s: standing, no course
    # a step whose interval the history does not hold (here: samples from 0.5 s on) is skipped
    n = _online(t_ns, gyro, accel, tg, v).steps
    late = t_ns >= 500_000_000
    assert _online(t_ns[late], gyro[late], accel[late], tg, v).steps == n - 1


def test_a_run_fed_a_mirrored_gps_warns_and_reports_it(
    kitti_raw: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ds = load_dataset(kitti_raw)
    assert ds.gps is not None and ds.imu is not None
    options = RunOptions(init=InitOptions(mode="groundtruth"), use_mag=False)
    ned = replace(ds, gps=GpsStream(ds.gps.t_ns, ds.gps.p_W_G @ NED.T, ds.gps.v_W_G @ NED.T))
    deg = replace(ds, imu=ImuStream(ds.imu.t_ns, np.degrees(ds.imu.gyro_B), ds.imu.accel_B))
    with caplog.at_level(logging.WARNING, logger="svains.navigation.course_check"):
        reports = {name: run_method(d, "ins", options).report
                   for name, d in (("as recorded", ds), ("ned", ned), ("deg", deg))}  # fmt: skip
    assert reports["as recorded"]["gps_course_check"]["warned"] == []
    assert reports["as recorded"]["gps_course_check"]["cosine"] > 0.99
    assert reports["ned"]["gps_course_check"]["warned"] == ["gps"]
    assert reports["deg"]["gps_course_check"]["warned"] == ["gyro"]
    assert caplog.text.count("online input:") == 2


X_REVERSED = np.diag([-1.0, 1.0, 1.0])  # one axis wired the other way (LSM9DS1-style)


def test_a_mirrored_magnetometer_is_refused_on_load(village_30s: Path, tmp_path: Path) -> None:
    import shutil

    from svains.datasets.validate import mag_frame_turn
    from svains.errors import DatasetError

    cosine, n, turn_deg = mag_frame_turn(load_dataset(village_30s))  # type: ignore[misc]
    assert cosine > 0.9 and n >= 4 and turn_deg > 45
    copy = tmp_path / "data"
    shutil.copytree(village_30s, copy)
    csv = copy / "mav0/mag0/data.csv"
    header = csv.read_text().splitlines()[0]
    rows = np.loadtxt(csv, delimiter=",", comments="#", dtype=object)
    rows[:, 1] = [repr(-float(v)) for v in rows[:, 1]]
    csv.write_text(header + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    with pytest.raises(DatasetError, match=r"mag0/data\.csv: the magnetic field turns with the "
                       r"IMU instead of against it \(cosine -0\.9\d over"):  # fmt: skip
        load_dataset(copy)


def test_a_dead_magnetometer_has_no_mount_to_judge(village_30s: Path) -> None:
    """A dead (all-zero) magnetometer: the field's turns are all zero, whose cosine with the
    gyro's was 0 / 0 (a numpy warning on the fault bench's dead magnetometer)."""
    import warnings

    from svains.sensors.units import mag_turn_vs_gyro

    ds = load_dataset(village_30s)
    assert ds.mag is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert mag_turn_vs_gyro(ds.imu.t_ns, ds.imu.gyro_B, ds.imu.accel_B, ds.mag.t_ns,
                                np.zeros_like(ds.mag.m_S)) is None  # fmt: skip


def test_a_mirrored_magnetometer_fed_online_is_warned_and_left_out(
    village_30s: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ds = load_dataset(village_30s)
    assert ds.mag is not None
    mirrored = replace(ds, mag=replace(ds.mag, m_S=ds.mag.m_S @ X_REVERSED.T))
    options = RunOptions(init=InitOptions(mode="groundtruth"))
    with caplog.at_level(logging.WARNING, logger="svains.navigation.course_check"):
        ok = run_method(ds, "ins", options).report
        bad = run_method(mirrored, "ins", options).report
    assert ok["mag_turn_check"]["warned"] is False and ok["mag_turn_check"]["cosine"] > 0.9
    assert bad["mag_turn_check"]["warned"] is True and bad["mag_turn_check"]["cosine"] < -0.7
    assert caplog.text.count("online input: the magnetic field turns with the IMU") == 1
    # from the warning on the samples are left out
    fused = bad["measurements"]["mag"]["fused"] + bad["measurements"]["mag"]["rejected"]
    assert bad["mag_held_skipped"] > 0.5 * ok["measurements"]["mag"]["fused"] > fused / 2
