"""A GPS that gives position only (NMEA GGA, many hobby and survey receivers): ``gps0`` rows of
4 fields read and written, the in-flight start from three differenced fixes, no start
zero-velocity update on a moving vehicle, and runs as accurate as with velocities."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.asl_reader import read_gps
from svains.datasets.asl_writer import AslWriter
from svains.datasets.types import GpsStream
from svains.errors import DatasetError
from svains.evaluation.run import run_method
from svains.navigation.init import GpsArrays, _with_start_velocities
from svains.navigation.options import InitOptions, RunOptions
from svains.sensors.types import GpsCalib

YAML = """%YAML:1.0
sensor_type: gps
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0]
rate_hz: 2.0
position_noise_std: 0.5
"""


def _gps_folder(tmp_path: Path, rows: list[str]) -> Path:
    d = tmp_path / "gps0"
    d.mkdir()
    (d / "sensor.yaml").write_text(YAML)
    (d / "data.csv").write_text("#timestamp [ns],p_WG_x [m],p_WG_y [m],p_WG_z [m]\n"
                                + "\n".join(rows) + "\n")  # fmt: skip
    return d


def test_rows_of_four_fields_are_positions_without_velocity(tmp_path: Path) -> None:
    d = _gps_folder(tmp_path, ["0,1.0,2.0,3.0", "500000000,1.5,2.0,3.0", "1000000000,2,2,3"])
    stream, calib = read_gps(d)
    assert stream.p_W_G[1].tolist() == [1.5, 2.0, 3.0]
    assert np.isnan(stream.v_W_G).all() and not stream.has_velocity.any()
    # no velocity_noise_std in sensor.yaml: that of two fixes one period apart
    assert calib.velocity_noise_std == pytest.approx(np.sqrt(2) * 0.5 * 2.0)
    # checks that need a course get it from the positions
    assert stream.velocity_or_differenced()[1].tolist() == pytest.approx([1.0, 0.0, 0.0])


def test_a_file_mixing_layouts_or_with_another_count_names_the_line(tmp_path: Path) -> None:
    d = _gps_folder(tmp_path, ["0,1,2,3,0,0,0", "500000000,1.5,2,3"])
    with pytest.raises(DatasetError, match=r"gps0/data\.csv:3: malformed row, 4 fields where "
                                           r"the rows before have 7"):  # fmt: skip
        read_gps(d)
    (d / "data.csv").write_text("#t\n0,1,2,3,4\n")
    with pytest.raises(DatasetError, match=r"data\.csv:2: malformed row, expected 7 or 4 fields, "
                                           r"got 5"):  # fmt: skip
        read_gps(d)


def test_position_only_fixes_are_written_as_four_fields_and_read_back(tmp_path: Path) -> None:
    t = np.array([0, 1_000_000_000, 2_000_000_000], np.int64)
    p = np.array([[0.0, 0, 0], [1, 2, 3], [2, 4, 6]])
    calib = GpsCalib(np.zeros(3), 1.0, 0.4, 0.6)
    w = AslWriter(tmp_path / "ds")
    folder = w.write_gps(GpsStream(t, p, np.full((3, 3), np.nan)), calib)
    header = (folder / "data.csv").read_text().splitlines()[0]
    assert header.count(",") == 3
    back, back_calib = read_gps(folder)
    assert np.array_equal(back.t_ns, t) and np.allclose(back.p_W_G, p)
    assert not back.has_velocity.any() and back_calib.velocity_noise_std == 0.6
    v = np.zeros((3, 3))
    v[1] = np.nan
    with pytest.raises(DatasetError, match="1 of 3 fixes have no velocity"):
        w.write_gps(GpsStream(t, p, v), calib, name="gps1")


def test_the_start_velocities_of_exact_fixes_are_the_true_ones() -> None:
    # p(t) = p0 + v0 t + a t² / 2 sampled at uneven fix times: two differences give v0 and a
    v0, a = np.array([3.0, -1.0, 0.5]), np.array([0.4, 0.2, -0.1])
    ts = np.array([0.0, 1.0, 2.5])
    p = ts[:, None] * v0 + 0.5 * ts[:, None] ** 2 * a
    gps = GpsArrays((ts * 1e9).astype(np.int64), p, np.full((3, 3), np.nan))
    got, accel_std, v0_std = _with_start_velocities(gps, "exact", 1e-9, 1.0)
    assert got.v_W_G[0] == pytest.approx(v0, abs=1e-6)
    assert got.v_W_G[1] == pytest.approx(v0 + a * 1.0, abs=1e-6)
    assert accel_std < 1e-6 and v0_std < 1e-8
    # 1 Hz fixes of 1.41 m: the second difference (3.46 m/s² std) shrinks to the 1 m/s² prior
    noisy, std, v0_std = _with_start_velocities(replace(gps, t_ns=np.array([0, 1, 2]) * 10**9),
                                                "noisy", np.sqrt(2), 1.0)  # fmt: skip
    assert std == pytest.approx(1.0 / np.sqrt(1 + 1 / 12), rel=1e-9)
    # the first velocity: a difference of two 1.41 m fixes 1 s apart (2 m/s), less half the
    # interval's acceleration
    assert v0_std == pytest.approx(np.hypot(2.0, 0.5 * std), rel=1e-9)
    # fixes with velocities: none of it
    assert _with_start_velocities(replace(gps, v_W_G=np.zeros((3, 3))), "v", 1.0, 1.0)[1:] == (
        0.0, 0.0)
    ratio = 1.0 / (1.0 + 12.0)
    a_fix = (p[2] - 2 * p[1] + p[0])
    assert noisy.v_W_G[1] - noisy.v_W_G[0] == pytest.approx(ratio * a_fix)


def test_gps_start_without_velocity_needs_three_fixes() -> None:
    from svains.errors import InitialisationError

    gps = GpsArrays(np.array([0, 10**9]), np.zeros((2, 3)), np.full((2, 3), np.nan))
    with pytest.raises(InitialisationError, match="without velocity needs at least 3 fixes"):
        _with_start_velocities(gps, "two", 0.5, 1.0)


@pytest.fixture(scope="module")
def kitti_positions(kitti_raw: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """KITTI raw with its gps0 cut to positions (and no velocity_noise_std)."""
    root = tmp_path_factory.mktemp("kitti_positions")
    shutil.copytree(kitti_raw, root, dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("cam0", "cam1"))  # fmt: skip
    gps = root / "mav0" / "gps0"
    rows = [",".join(r.split(",")[:4]) for r in (gps / "data.csv").read_text().splitlines()]
    (gps / "data.csv").write_text("\n".join(rows) + "\n")
    yaml = (gps / "sensor.yaml").read_text().splitlines()
    (gps / "sensor.yaml").write_text("\n".join(r for r in yaml if "velocity_noise_std" not in r))
    return root


def test_kitti_in_flight_start_from_positions_alone(kitti_raw: Path, kitti_positions: Path) -> None:
    options = RunOptions(init=InitOptions(mode="gps"), use_mag=False)
    full = run_method(load_dataset(kitti_raw), "ins", options).report
    ds = load_dataset(kitti_positions)
    assert ds.gps is not None and not ds.gps.has_velocity.any()
    got = run_method(ds, "ins", options).report
    assert got["init"]["mode"] == "gps" and got["init"]["heading"] == "gps course"
    assert 0.4 < got["init"]["gps_acceleration_std"] < 1.0  # 0.35 m fixes at 1 Hz, shrunk
    # a cruising car is not at rest: no start zero-velocity update (it zeroed 4.7 m/s)
    assert "zupt" not in got["measurements"]
    assert got["measurements"]["gps"]["rejected"] == 0
    # 2026-12-05: 0.264 m (NEES 1.65) against 0.275 m (4.57) with the recorded velocities
    assert got["position_rmse_m"] < 1.2 * full["position_rmse_m"]
    assert got["nees_mean"] < 9.0
