"""Who moved, the camera or the filter: a vision frame refused right after a fused one, GPS-denied
(``navigation.camera_continuity``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import ImuStream
from svains.evaluation.run import run_method
from svains.navigation.camera_continuity import MAX_GAP_S, MAX_SINCE_FUSED_S, CameraContinuity
from svains.replay import resolve_config

S = 1_000_000_000
STD = np.array([0.01, 0.05])  # rad/s, m/s: the egomotion's noise per second


def _agreed(v_mps: float = 9.0) -> CameraContinuity:
    c = CameraContinuity()
    c.fused(10 * S, np.array([0.0, 0.01, 0.0, 0.0, 0.0, -v_mps]))
    return c


def test_the_camera_carrying_on_blames_the_filter_a_camera_that_stops_does_not() -> None:
    agreed = _agreed()
    assert agreed.agreed is not None
    # a missed IMU burst: the camera sees the car drive on, the filter predicts 4 m/s more
    # and a turn
    measured = agreed.agreed + np.array([0.0, 0.002, 0.0, 0.0, 0.0, -0.05])
    predicted = agreed.agreed + np.array([0.0, 0.4, 0.0, 0.5, 0.0, -4.0])
    assert agreed.filter_moved(measured, STD, predicted)
    # a stuck or replayed view: the camera measures no motion, the filter drives on
    still = np.zeros(6)
    assert not agreed.filter_moved(still, STD, agreed.agreed + 0.01)
    # a stuck view as a hover ends: the camera measures no motion, the filter sets off
    hover = CameraContinuity()
    hover.fused(10 * S, np.zeros(6))
    assert not hover.filter_moved(np.zeros(6), STD, np.array([0, 0, 0, 0, 0, -1.5]))
    # both moved alike (the motion changed, or both are off): nothing concluded
    assert not agreed.filter_moved(predicted, STD, predicted)
    # a prediction off by less than the camera's noise: nothing concluded
    assert not agreed.filter_moved(agreed.agreed, STD,
                                   agreed.agreed + np.array([0, 0, 0, 0, 0, -0.1]))  # fmt: skip
    # only short frames, soon after the fused one
    assert agreed.may_judge(10 * S + S, 0.2)
    assert not agreed.may_judge(10 * S + S, MAX_GAP_S + 0.1)
    assert not agreed.may_judge(10 * S + round((MAX_SINCE_FUSED_S + 0.1) * S), 0.2)
    assert not CameraContinuity().may_judge(S, 0.1)


def _burst_run(kitti_raw: Path, blame: bool, monkeypatch: pytest.MonkeyPatch) -> dict:
    """KITTI raw `3d` GPS-denied from images, 16 s, with 0.3 s of plausible IMU readings off by
    15 m/s² and 1 rad/s from 8 s (no check of the IMU can see them: no spike, no rail)."""
    if not blame:
        monkeypatch.setattr(CameraContinuity, "filter_moved", lambda self, *a: False)
    ds = load_dataset(kitti_raw)
    assert ds.imu is not None
    t = ds.imu.t_ns
    burst = (t >= t[0] + 8 * S) & (t < t[0] + round(8.3 * S))
    gyro, accel = ds.imu.gyro_B.copy(), ds.imu.accel_B.copy()
    gyro[burst, 2] += 1.0
    accel[burst, 0] += 15.0
    faulty = replace(ds, imu=ImuStream(t, gyro, accel))
    config = build_config(None, [], {"method": "3d", "init.mode": "groundtruth",
                                     "use_gps": False, "use_mag": False,
                                     "vision.source": "images", "duration_s": 16.0})  # fmt: skip
    return run_method(faulty, None, resolve_config(faulty, config)).report


def test_a_missed_imu_burst_is_the_filters_and_vision_brings_it_back(
    kitti_raw: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A user's probe: an IMU burst the checks missed took the state away, the next frame was
    taken for a jump of the camera and vision was refused for the rest of the run (277 m ATE).
    Now the frame's camera motion, carrying on the last fused frame's while the prediction left
    it, blames the filter: it is inflated and vision takes it back."""
    report = _burst_run(kitti_raw, True, monkeypatch)
    assert report["recovery"]["filter_moved"] >= 1
    assert report["recovery"]["jumps"] == 0
    v = report["vision"]
    assert v["frames_fused"] >= 0.9 * v["frames"]
    # the samples since the last fused frame are left out of the calibration checks (the
    # burst read as the camera's stamps 300 ms off)
    assert v["rotation_check"]["warned_time_offset"] is False
    with monkeypatch.context() as m:
        before = _burst_run(kitti_raw, False, m)
    assert before["recovery"]["jumps"] >= 1
    assert before["vision"]["frames_fused"] < 0.8 * before["vision"]["frames"]
    assert report["ate_rmse_m"] < 0.5 * before["ate_rmse_m"]
