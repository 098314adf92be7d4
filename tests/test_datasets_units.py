"""Unit, clock and frame mistakes a file's syntax cannot show, told from the values on load:
the GPS frame's handedness against the IMU's turns (``datasets.validate``), the accelerometer's
unit (``sensors.units``). The corpus of one-line CLI errors is in ``test_cli_bad_input.py``."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.validate import gps_course_vs_imu_turn
from svains.errors import DatasetError
from svains.sensors.units import accel_units_problem

G_W = np.array([0.0, 0.0, -9.81])


def _drive(rate_z: np.ndarray, t: np.ndarray, speed: float = 8.0, sideways: bool = False):
    """A level vehicle yawing at ``rate_z`` (rad/s, about up) over ``t`` (s); IMU at 100 Hz and
    1 Hz GPS velocities in ENU. ``sideways``: the course turns while the body does not (the
    velocity follows ``rate_z``, the gyro reads nothing), as a multirotor can fly."""
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate_z[1:] + rate_z[:-1]) * np.diff(t))])
    rng = np.random.default_rng(0)
    gyro = np.zeros((t.size, 3))
    gyro[:, 2] = 0.0 if sideways else rate_z
    gyro += rng.normal(0.0, 1e-3, gyro.shape)
    accel = np.tile([0.0, 0.0, 9.81], (t.size, 1)) + rng.normal(0.0, 0.05, (t.size, 3))
    t_ns = (t * 1e9).astype(np.int64)
    idx = np.arange(0, t.size, 100)
    v = speed * np.stack([np.cos(yaw[idx]), np.sin(yaw[idx]), np.zeros(idx.size)], axis=1)
    return t_ns, gyro, accel, t_ns[idx], v


def test_the_gps_course_follows_the_gyro_and_a_mirror_turns_it_against() -> None:
    t = np.arange(0.0, 40.0, 0.01)
    rate = 0.3 * np.sin(2 * np.pi * t / 12.0)  # weaving left and right
    t_ns, gyro, accel, tg, v = _drive(rate, t)
    cosine, n, turn, ratio = gps_course_vs_imu_turn(t_ns, gyro, accel, tg, v, G_W)
    assert cosine > 0.99 and n >= 20 and turn > 200 and abs(ratio - 1.0) < 0.05
    ned = v[:, [1, 0, 2]] * [1, 1, -1]  # north, east, down
    assert gps_course_vs_imu_turn(t_ns, gyro, accel, tg, ned, G_W)[0] < -0.99
    # the same mirror against a gravity that says z is down is consistent
    assert gps_course_vs_imu_turn(t_ns, gyro, accel, tg, ned, -G_W)[0] > 0.99


def test_a_vehicle_flying_sideways_gives_no_turn_to_compare() -> None:
    t = np.arange(0.0, 40.0, 0.01)
    t_ns, gyro, accel, tg, v = _drive(0.3 * np.sin(2 * np.pi * t / 12.0), t, sideways=True)
    assert gps_course_vs_imu_turn(t_ns, gyro, accel, tg, v, G_W) is None


@pytest.fixture
def kitti_copy(kitti_raw: Path, tmp_path: Path) -> Path:
    """KITTI raw with its gps0 and imu0 copied (to be edited) and every other entry linked."""
    root = tmp_path / "kitti"
    (root / "mav0").mkdir(parents=True)
    for entry in (kitti_raw / "mav0").iterdir():
        if entry.name in ("gps0", "imu0"):
            shutil.copytree(entry, root / "mav0" / entry.name)
        else:
            os.symlink(entry, root / "mav0" / entry.name)
    return root


def test_a_gps_in_ned_on_real_data_is_refused_naming_the_frame(kitti_copy: Path) -> None:
    load_dataset(kitti_copy)  # as shipped: ENU, read without complaint
    path = kitti_copy / "mav0/gps0/data.csv"
    lines = path.read_text().splitlines()
    rows = [[float(v) for v in ln.split(",")[1:]] for ln in lines[1:]]
    out = [lines[0]]
    for ln, (x, y, z, vx, vy, vz) in zip(lines[1:], rows, strict=True):
        ned = (y, x, -z, vy, vx, -vz)
        out.append(",".join([ln.split(",")[0], *(repr(c) for c in ned)]))
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(DatasetError, match=r"gps0/data\.csv: the GPS course turns against the "
                       r"IMU \(cosine -0\.99 over 8 turns.*mirrored.*\(NED, or two axes"):
        load_dataset(kitti_copy)


def test_a_gyro_in_deg_s_on_real_data_is_refused(kitti_copy: Path) -> None:
    path = kitti_copy / "mav0/imu0/data.csv"
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        t, *v = ln.split(",")
        out.append(",".join([t, *(repr(float(np.degrees(float(x)))) for x in v[:3]), *v[3:]]))
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(DatasetError, match=r"imu0/data\.csv: the gyro turns 5\d\.\d times as far "
                       r"as the GPS course \(cosine 0\.99 over \d+ turns\): is it in deg/s\?"):
        load_dataset(kitti_copy)


def test_gps_stamps_on_another_clock_are_found_from_the_turns() -> None:
    """Fixes stamped 18 s late (GPS time against an IMU in UTC) or 1 s early: the course
    matches the gyro at that shift; the stamps as given, and a multirotor flying sideways,
    give nothing to refuse."""
    from svains.sensors.units import gps_clock_problem, gps_clock_shift

    t = np.arange(0.0, 90.0, 0.01)
    rate = 0.3 * np.sin(2 * np.pi * t / 12.0) * (1.0 + 0.5 * np.sin(2 * np.pi * t / 31.0))
    t_ns, gyro, accel, tg, v = _drive(rate, t)
    shift, cosine, given, n = gps_clock_shift(t_ns, gyro, accel, tg, v, G_W)
    assert abs(shift) < 0.1 and cosine > 0.99 and gps_clock_problem(shift, cosine, given, n) is None
    for tau in (18.0, -1.0):
        got = gps_clock_shift(t_ns, gyro, accel, tg + int(tau * 1e9), v, G_W)
        assert got is not None and abs(got[0] - tau) <= 0.1 and got[1] > 0.99 and got[2] < 0.89
        why = gps_clock_problem(*got)
        assert why is not None and f"timeshift_gps_imu: {-tau:.1f}" in why
    t_ns, gyro, accel, tg, v = _drive(rate, t, sideways=True)
    got = gps_clock_shift(t_ns, gyro, accel, tg, v, G_W)
    assert got is None or gps_clock_problem(*got) is None


def test_gps_stamps_a_second_late_on_real_data_are_refused(kitti_copy: Path) -> None:
    path = kitti_copy / "mav0/gps0/data.csv"
    lines = path.read_text().splitlines()
    out = [lines[0], *(",".join([str(int(ln.split(",")[0]) + 10**9), *ln.split(",")[1:]])
                       for ln in lines[1:])]  # fmt: skip
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(DatasetError, match=r"gps0/data\.csv: the GPS course turns with the gyro "
                       r"when its stamps are moved \+1\.\d s .*stamped about 1\.\d s late "
                       r".*timeshift_gps_imu: -1\.\d in gps0/sensor\.yaml"):
        load_dataset(kitti_copy)


@pytest.mark.parametrize(
    ("scale", "remove_gravity", "guess"),
    [(1.0, False, None), (1 / 9.81, False, "looks like g "), (1000 / 9.81, False, "like mg"),
     (1 / 0.3048, False, "like ft/s²"), (1.0, True, "gravity removed"),
     (30.0, False, "another unit")],
)
def test_the_accelerometer_unit_is_named(scale: float, remove_gravity: bool,
                                         guess: str | None) -> None:  # fmt: skip
    rng = np.random.default_rng(1)
    # a vehicle's specific force: gravity along a wandering up plus manoeuvres of ~2 m/s²
    tilt = rng.normal(0.0, 0.1, (2000, 2))
    up = np.column_stack([tilt, np.ones(2000)])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    f = 9.81 * up * (0.0 if remove_gravity else 1.0) + rng.normal(0.0, 2.0, (2000, 3))
    problem = accel_units_problem(f * scale, G_W)
    if guess is None:
        assert problem is None
    else:
        assert problem is not None and guess in problem, problem


def test_gyro_and_accelerometer_columns_swapped_are_named() -> None:
    """A header-less CSV with the accelerometer's columns first (a user's probe) was told
    "gravity removed": the gyro's columns hold gravity's magnitude."""
    rng = np.random.default_rng(2)
    f = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.2, (500, 3))
    w = rng.normal(0.0, 0.05, (500, 3))
    problem = accel_units_problem(w, G_W, f)
    assert problem is not None and "are the gyro and accelerometer columns swapped?" in problem
    assert accel_units_problem(f, G_W, w) is None
    assert "gravity removed" in (accel_units_problem(w, G_W) or "")  # no rates: the old guess
    # an accelerometer in g beside a gyro in deg/s turning 15°/s is the unit, not a swap
    # (a review)
    turning = np.degrees(rng.normal(0.0, 0.05, (500, 3))) + np.array([0.0, 0.0, 15.0])
    said = accel_units_problem(f / 9.81, G_W, turning) or ""
    assert "looks like g (multiply by 9.81)" in said and "swapped" not in said


def test_a_principal_point_near_the_edge_warns_of_the_intrinsics_order(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from svains.datasets.validate import check_camera_calib
    from svains.sensors.types import CameraCalib

    def calib(intrinsics: list[float]) -> CameraCalib:
        return CameraCalib("cam0", np.eye(4), 20.0, (752, 480), np.array(intrinsics),
                           "radtan", np.zeros(4))  # fmt: skip

    with caplog.at_level("WARNING", logger="svains.datasets.validate"):
        check_camera_calib(calib([458.7, 457.3, 367.2, 248.4]), Path("cam0/sensor.yaml"))
        assert caplog.text == ""  # EuRoC's own
        check_camera_calib(calib([367.2, 248.4, 458.7, 457.3]), Path("cam0/sensor.yaml"))
    assert "principal point (458.7, 457.3) px lies near the edge of the 752x480" in caplog.text


def test_intrinsics_of_a_half_resolution_image_are_refused() -> None:
    """EuRoC's cam0 intrinsics halved against its 752x480 images (a calibration of binned
    images): runs ended 4-5 m off, exit 0; refused with the factor to scale them by. A
    principal point off the middle on one axis only (a cropped image) is read."""
    from svains.datasets.validate import check_camera_calib
    from svains.errors import CalibrationError
    from svains.sensors.types import CameraCalib

    def calib(intrinsics: list[float]) -> CameraCalib:
        return CameraCalib("cam0", np.eye(4), 20.0, (752, 480), np.array(intrinsics),
                           "radtan", np.zeros(4))  # fmt: skip

    with pytest.raises(CalibrationError, match=r"cam0/sensor\.yaml: the principal point "
                       r"\(183\.6, 124\.2\) px sits at 0\.50 times the middle of the 752x480 "
                       r"image on both axes: intrinsics of a 378x241 image\? Scale fu, fv, cu, "
                       r"cv by 1\.99"):
        check_camera_calib(calib([229.35, 228.65, 183.6, 124.2]), Path("cam0/sensor.yaml"))
    check_camera_calib(calib([458.7, 457.3, 200.0, 248.4]), Path("cam0/sensor.yaml"))


def test_an_imu_stream_faster_than_its_declared_rate_is_warned(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A 200 Hz stream declared 100 Hz: every sample would get half its white-noise variance.
    Warned on load with both rates; a stream slower than declared (KITTI raw keeps one OXTS
    record in four) and the written rate itself are read silently."""
    from test_datasets_roundtrip import write_full

    root = tmp_path / "ds"
    write_full(root)  # 200 Hz samples, rate_hz 200
    yaml_path = root / "mav0" / "imu0" / "sensor.yaml"
    text = yaml_path.read_text()
    with caplog.at_level("WARNING", logger="svains.datasets.validate"):
        load_dataset(root)
        assert "rate_hz" not in caplog.text
        yaml_path.write_text(text.replace("rate_hz: 200", "rate_hz: 800"))
        load_dataset(root)
        assert "rate_hz" not in caplog.text
        yaml_path.write_text(text.replace("rate_hz: 200", "rate_hz: 100"))
        load_dataset(root)
    assert ("imu0/data.csv: samples come at 200 Hz but sensor.yaml declares rate_hz 100: each "
            "sample is given the noise of a 100 Hz sensor, 2x too little variance") in caplog.text


@pytest.mark.parametrize(("scale", "fragment"), [(0.0, "integrate to 0 m"),
                                                 (3.6, "260 % off")])
def test_gps_velocities_that_are_not_the_positions_are_left_out(
    kitti_copy: Path, scale: float, fragment: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Velocity columns of zeros (or in km/h) beside sound positions were fused: `ins` ended
    152 m off, the positions blamed (a user's probe). Now warned and left out, as for a
    position-only receiver; the positions are used."""
    assert np.isfinite(load_dataset(kitti_copy).gps.v_W_G).all()  # as shipped: 0.6 % off
    path = kitti_copy / "mav0/gps0/data.csv"
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        t, *v = ln.split(",")
        out.append(",".join([t, *v[:3], *(repr(scale * float(x)) for x in v[3:])]))
    path.write_text("\n".join(out) + "\n")
    with caplog.at_level("WARNING"):
        ds = load_dataset(kitti_copy)
    assert "gps0/data.csv: the velocities integrate to" in caplog.text and fragment in caplog.text
    assert "the velocities are left out, the positions used" in caplog.text
    assert np.isnan(ds.gps.v_W_G).all() and np.isfinite(ds.gps.p_W_G).all()


def test_jittered_camera_stamps_are_named_and_keyframes_are_not(kitti_raw: Path) -> None:
    """Stamps taken on arrival scatter around the camera's rate; the estimator takes them as
    exact (a user's probe: ±20 ms on KITTI raw took `3d` from 0.28 to 1.66 m, not a word).
    Keyframes chosen 0.05-7 s apart are irregular by design and not judged."""
    from svains.datasets.validate import frame_jitter_problem

    rng = np.random.default_rng(5)
    t = np.arange(180) * 206_000_000
    assert frame_jitter_problem(t) is None
    jittered = t + rng.integers(-20_000_000, 20_000_001, t.size)
    why = frame_jitter_problem(jittered)
    assert why is not None and "ms period: stamps taken on arrival" in why
    assert 9.0 < float(why.split("about ")[1].split(" ms")[0]) < 15.0  # uniform ±20 ms: 11.5
    keyframes = np.cumsum(np.exp(rng.uniform(np.log(0.05), np.log(7.0), 100)) * 1e9)
    assert frame_jitter_problem(keyframes.astype(np.int64)) is None
    assert frame_jitter_problem(load_dataset(kitti_raw).left.t_ns) is None  # 0.12 ms


def test_an_imu_clipped_below_an_undeclared_range_is_found(
    kitti_copy: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Readings held at a full scale that sensor.yaml does not give were fused as true (a
    user's probe: a gyro clipped at 0.6 rad/s on 3 % of EuRoC's samples, `3d` 4.1 m off)."""
    assert load_dataset(kitti_copy).imu_calib.gyro_range is None  # as shipped: nothing held
    path = kitti_copy / "mav0/imu0/data.csv"
    lines = path.read_text().splitlines()
    out, clipped = [lines[0]], 0
    for ln in lines[1:]:
        t, *v = ln.split(",")
        g = np.clip([float(x) for x in v[:3]], -0.2, 0.2)
        clipped += int(np.any(np.abs(g) == 0.2))
        out.append(",".join([t, *(repr(float(x)) for x in g), *v[3:]]))
    path.write_text("\n".join(out) + "\n")
    assert clipped >= 10
    with caplog.at_level("WARNING"):
        ds = load_dataset(kitti_copy)
    assert "the gyroscope's readings are held at ±0.2 rad/s" in caplog.text
    assert ds.imu_calib.gyro_range == 0.2 and ds.imu_calib.accel_range is None


def test_a_quantised_gyros_repeated_peak_is_no_full_scale() -> None:
    """A 16-bit gyro (70 mdps steps) repeats its peak rate for a few samples in a slow turn:
    read as clipped, its peak then taken as the range (a user's probe)."""
    from svains.datasets.validate import clipping_range

    rng = np.random.default_rng(6)
    t = np.arange(0.0, 60.0, 0.005)
    step = np.radians(0.07)
    w = 0.6 * np.sin(0.5 * t) + 2e-4 * rng.standard_normal(t.size)
    quantised = np.round(w / step) * step
    assert clipping_range(np.column_stack([quantised, 0 * t, 0 * t])) is None
    noisy = 0.6 * np.sin(0.5 * t) + 0.01 * rng.standard_normal(t.size)
    assert clipping_range(np.column_stack([np.clip(noisy, -0.5, 0.5), 0 * t, 0 * t])) == 0.5


def test_a_camera_changing_or_drifting_rate_is_no_jitter_and_drops_are_not_either() -> None:
    """Exact hardware stamps at a rate that changes (30 -> 25 -> 20 Hz) or drifts were warned
    as jitter (a user's probe); dropped frames neither; jitter with drops still is."""
    from svains.datasets.validate import frame_jitter_problem

    rng = np.random.default_rng(8)
    steps = np.concatenate([np.full(200, 1 / 30), np.full(200, 1 / 25), np.full(200, 1 / 20)])
    assert frame_jitter_problem((np.cumsum(steps) * 1e9).astype(np.int64)) is None
    drift = 0.030 + 0.010 * np.sin(np.linspace(0.0, 6.0, 600))
    assert frame_jitter_problem((np.cumsum(drift) * 1e9).astype(np.int64)) is None
    t = np.arange(600) / 20.0
    keep = rng.random(600) > 0.3
    assert frame_jitter_problem((t[keep] * 1e9).astype(np.int64)) is None
    jittered = t + rng.uniform(-0.01, 0.01, t.size)
    why = frame_jitter_problem((jittered[keep] * 1e9).astype(np.int64))
    assert why is not None and 4.0 < float(why.split("about ")[1].split(" ms")[0]) < 8.0


def test_gravity_with_the_wrong_sign_is_told_from_the_ground_truth() -> None:
    """``gravity_W`` [0, 0, +9.81] (a z-down world) passed the size check alone: 50 m off from a
    ground-truth start, a static start upside down (a user's probe). The reference's attitudes
    turn the IMU's specific force, averaged over the run, up; against gravity_W it is 180°."""
    from dataclasses import replace

    from _ins_truth import make_dataset
    from svains.datasets.validate import gravity_reference_problem

    ds = make_dataset(20.0)
    assert gravity_reference_problem(ds) is None
    flipped = replace(ds, gravity_W=-np.asarray(ds.gravity_W))
    said = gravity_reference_problem(flipped)
    assert said is not None
    assert re.search(r"1[78]\d° from up \(-gravity_W \[0.0, 0.0, -9.81\]\)", said)
    assert "z-down world?" in said
    # or the IMU's own axes (a user's probe: a forward-right-down IMU given identity)
    assert "an IMU in other axes than imu0's T_BS says" in said
    # no reference, nothing to say
    assert gravity_reference_problem(replace(flipped, groundtruth=None)) is None


def test_a_chance_match_over_few_turns_is_no_gps_clock_error(tmp_path: Path) -> None:
    """A simulated helicopter circling, stamps right (10 Hz GPS, 40 s, seed 2): its course
    matched the gyro 0.93 at +5.8 s against 0.76 as stamped over 6 turns, and the data set
    was refused (a review): the shift's gain over the stamps, F = 5 (0.93² - 0.76²) /
    (1 - 0.93²) = 10, is what the best of 1200 shifts finds by chance over 6 noisy turns.
    KITTI raw's stamps moved by 1 s (F 10^4), and a car whose course is noisy (σ 0.6 m/s,
    0.92 against 0.82 over 104 turns, F 120) are still refused (a review)."""
    from dataclasses import replace

    from svains.sensors.units import gps_clock_problem
    from svains.sim import SimConfig, simulate

    assert gps_clock_problem(5.75, 0.927, 0.756, 6) is None
    assert gps_clock_problem(1.10, 0.999, 0.359, 8) is not None  # KITTI raw, +1 s
    assert gps_clock_problem(1.00, 0.921, 0.819, 104) is not None
    assert gps_clock_problem(18.0, 0.920, -0.863, 103) is not None  # against it as stamped
    cfg = SimConfig(duration_s=40.0, seed=2)
    cfg = replace(cfg, gps=replace(cfg.gps, rate_hz=10.0, outages=[]),
                  camera=replace(cfg.camera, render_images=False))  # fmt: skip
    ds = load_dataset(simulate(cfg, tmp_path / "ds"))
    assert ds.gps is not None and len(ds.gps.t_ns) == 401
