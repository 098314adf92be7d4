"""Issue 23: a 5 s IMU gap on the real EuRoC IMU (``ins``, the first 10 s, static start). The
MAV rests until 5.5 s and takes off inside the gap; bridged between the two raw end samples
(rotors on: vibrating), the run ended 31 m off; the bridge now holds the rest (the IMU rested
before the gap) between window means, and the start's zero-velocity updates end at the gap."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.cli.run_config import build_config
from svains.datasets import load_dataset
from svains.datasets.types import ImuStream
from svains.evaluation.run import run_method
from svains.replay import resolve_config

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
S = 1_000_000_000


def _ins(euroc_micro: Path, gap_at_s: float | None) -> dict:
    ds = load_dataset(euroc_micro)
    assert ds.imu is not None
    if gap_at_s is not None:
        t = ds.imu.t_ns
        t0 = int(t[0]) + round(gap_at_s * S)
        keep = ~((t >= t0) & (t < t0 + 5 * S))
        ds = replace(ds, imu=ImuStream(t[keep], ds.imu.gyro_B[keep], ds.imu.accel_B[keep]))
    config = build_config(None, [], {"method": "ins", "init.mode": "static", "duration_s": 10.0})
    return run_method(ds, None, resolve_config(ds, config)).report


def test_a_5_s_gap_across_the_take_off_stays_within_a_metre(euroc_micro: Path) -> None:
    # Measured 2026-12-02 (python bench/real_imu_gap.py ../shared/data/euroc_v101_micro --method
    # ins --duration 10 --init static --at 2 --clean, and --at 3): ATE 0.073 m
    # clean; gap at 2 s: 1.01 m (31.2 m with the raw end samples, 20.0 m with window means
    # but the chord); at 3 s: 0.68 m. Limits 1.5x. The line, 5x clean, is not met:
    # the take-off inside the gap is unobservable to an unaided INS.
    at2, at3 = _ins(euroc_micro, 2.0), _ins(euroc_micro, 3.0)
    assert at2["imu_faults"]["gaps"] == 1 and 4.9 < at2["imu_faults"]["longest_gap_s"] < 5.1
    assert at2["ate_rmse_m"] < 1.5
    assert at3["ate_rmse_m"] < 1.0
    # consistent across the bridge in roll and pitch (2 dof): measured 0.46 / 0.36
    assert at2["nees_blocks"]["roll_pitch"] < 2.0 and at3["nees_blocks"]["roll_pitch"] < 2.0
    assert np.isfinite(at2["nees_mean"])


def test_the_posyaw_alignment_of_a_short_static_start_takes_its_yaw_from_the_headings(
    euroc_micro: Path,
) -> None:
    # The first 10 s: a rest, then 0.8 m of flight. With headings weighed like positions at
    # 0.1 m, the yaw came from positions that move by little more than their error: attitude
    # error 32.7°, yaw NEES 395. Measured with the 3 m lever: 0.90°, yaw NEES 0.0 (limit 1.5x).
    clean = _ins(euroc_micro, None)
    assert clean["errors_alignment"] == "posyaw"
    assert clean["attitude_rmse_deg"] < 1.35
    assert clean["nees_blocks"]["yaw"] < 1.0
