"""An in-flight start's first GPS fixes checked against the accelerometer (``init._from_gps``):
the specific force their velocities imply must have the magnitude the IMU measured, or the
next pair starts it (``navigation.starter``)."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from _flights import gps_flight
from svains.datasets import load_dataset
from svains.datasets.types import Dataset
from svains.errors import InitialisationError
from svains.evaluation.run import run_method
from svains.navigation.options import InitOptions, ReplayOptions, RunConfig


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The village at 2 m/s, 45 s, GPS at 1 Hz throughout, features only."""
    return gps_flight(tmp_path_factory.mktemp("start_fixes") / "flight", 45.0, 13)


def _velocities_changed(ds: Dataset, at_s: list[float], dv: list[np.ndarray]) -> Dataset:
    assert ds.gps is not None
    v = ds.gps.v_W_G.copy()
    t_s = (ds.gps.t_ns - ds.imu.t_ns[0]) * 1e-9
    for a, d in zip(at_s, dv, strict=True):
        v[int(np.argmin(np.abs(t_s - a)))] += d
    return replace(ds, gps=replace(ds.gps, v_W_G=v))


def _config(start_s: float) -> RunConfig:
    return RunConfig(method="3d", init=InitOptions(mode="gps"), use_mag=False,
                     replay=ReplayOptions(start_s=start_s), duration_s=15.0)  # fmt: skip


def test_a_glitched_velocity_in_the_start_fixes_waits_for_the_next_pair(
    flight: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The fix at 31 s with its velocity reversed (4 m/s² on a steady 2 m/s flight): the
    start took it, 22° tilted and held to 3°, and `3d` ended 288 m off (a user's probe). Both
    pairs holding it are refused, warned; the start takes the pair after."""
    ds = load_dataset(flight)
    assert ds.gps is not None
    k = int(np.argmin(np.abs((ds.gps.t_ns - ds.imu.t_ns[0]) * 1e-9 - 31.0)))
    bad = _velocities_changed(ds, [31.0], [-2.0 * ds.gps.v_W_G[k]])
    with caplog.at_level(logging.WARNING, logger="svains.navigation.starter"):
        rep = run_method(bad, "3d", _config(30.0)).report
    waits = [r.getMessage() for r in caplog.records if "waits for the next GPS fix" in r.message]
    assert len(waits) == 2 and "a fix's velocity is wrong" in waits[0], waits
    clean = run_method(ds, "3d", _config(32.0)).report
    assert rep["ate_rmse_m"] < 1.5 and rep["nees_mean"] < 20.0
    assert rep["ate_rmse_m"] < 2.0 * clean["ate_rmse_m"]


def test_fixes_that_never_agree_with_the_accelerometer_stop_the_start_in_one_line(
    flight: Path,
) -> None:
    ds = load_dataset(flight)
    at = [float(s) for s in range(30, 38)]
    jumps = [np.array([3.0 * (-1) ** i, 0.0, 0.0]) for i in range(len(at))]
    why = (r"^5 pairs of GPS fixes in a row disagree with the accelerometer or each other "
           r"\(the last: the GPS fixes at .* imply a specific force of .* m/s², the "
           r"accelerometer measured .*\)")
    with pytest.raises(InitialisationError, match=why):
        run_method(_velocities_changed(ds, at, jumps), "3d", _config(30.0))


def test_a_jumped_position_in_the_start_fixes_waits_for_the_next_pair(
    flight: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The fix at 30 s 40 m east: it placed the start, and the agreeing fixes after it were
    refused by the gate until the filter was inflated (a user's probe: 17.3 m). The first
    pair's positions are 42 m apart where their velocities moved the antenna 2 m."""
    ds = load_dataset(flight)
    assert ds.gps is not None
    k = int(np.argmin(np.abs((ds.gps.t_ns - ds.imu.t_ns[0]) * 1e-9 - 30.0)))
    p = ds.gps.p_W_G.copy()
    p[k, 0] += 40.0
    bad = replace(ds, gps=replace(ds.gps, p_W_G=p))
    with caplog.at_level(logging.WARNING, logger="svains.navigation.starter"):
        rep = run_method(bad, "3d", _config(30.0)).report
    waits = [r.getMessage() for r in caplog.records if "waits for the next GPS fix" in r.message]
    assert len(waits) == 1 and "a fix's position jumped" in waits[0], waits
    assert rep["ate_rmse_m"] < 1.5 and rep["nees_mean"] < 20.0


def test_fixes_released_together_start_the_pair_after_a_refused_one(flight: Path) -> None:
    """Fixes released in one batch (a run fed its GPS ahead of the IMU): the Starter kept
    only those of the first complete selection, and after that pair was refused the next
    pair's fixes were gone: the start never came (a review). The glitched fix at 31 s is in
    two pairs; the third starts the run."""
    from svains.models.state import BIASED
    from svains.navigation.imu_history import ImuHistory
    from svains.navigation.starter import Starter
    from svains.replay import rig_from_dataset

    ds = load_dataset(flight)
    assert ds.gps is not None and ds.imu is not None
    t_s = (ds.gps.t_ns - ds.imu.t_ns[0]) * 1e-9
    k = int(np.argmin(np.abs(t_s - 31.0)))
    bad = _velocities_changed(ds, [31.0], [-2.0 * ds.gps.v_W_G[k]])
    assert bad.gps is not None
    starter = Starter(InitOptions(mode="gps"), rig_from_dataset(ds), BIASED, None)
    for j in range(k - 1, k + 5):  # 30-35 s at once
        starter.add_gps(int(bad.gps.t_ns[j]), bad.gps.p_W_G[j], bad.gps.v_W_G[j])
    history = ImuHistory()
    end_ns = int(bad.gps.t_ns[k + 5])
    sel = np.flatnonzero((ds.imu.t_ns >= bad.gps.t_ns[k - 1] - 10**9) & (ds.imu.t_ns <= end_ns))
    for i in sel:
        history.append(int(ds.imu.t_ns[i]), ds.imu.gyro_B[i], ds.imu.accel_B[i])
    got = [starter.try_start(history, end_ns) for _ in range(3)]
    assert got[0] is None and got[1] is None and got[2] is not None
    assert got[2].t_ns >= bad.gps.t_ns[k + 1]
    np.testing.assert_allclose(got[2].x[:3], ds.groundtruth.p_W_B[
        np.argmin(np.abs(ds.groundtruth.t_ns - got[2].t_ns))], atol=1.0)
