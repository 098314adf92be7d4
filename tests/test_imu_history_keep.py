"""Bounded IMU history (``buffer.imu_keep_s``): dropping old samples changes no value, and a run
whose history keeps letting samples go equals the run that keeps them all."""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import svains.navigation.navigator as navigator_module
from _golden_cases import CASES, case_options, load_case_dataset
from svains.navigation.imu_history import ImuHistory
from svains.navigation.navigator import Navigator
from svains.replay.replay import feed, groundtruth_start, measurements, rig_from_dataset


def _samples(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(4)
    t = 1_000_000_000 + np.cumsum(rng.integers(4_000_000, 6_000_000, n))  # irregular spacing
    return t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3))


def test_dropping_old_rows_keeps_every_value_of_the_recent_ones() -> None:
    t, g, a = _samples(300)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    full, kept = ImuHistory(R), ImuHistory(R, capacity=16)
    for k in range(t.size):
        full.append(int(t[k]), g[k], a[k])
        kept.append(int(t[k]), g[k], a[k])
        kept.keep_from_ns = int(t[k]) - 30_000_000  # ~6 samples back
        if k % 7 == 0:
            kept.alpha_B  # noqa: B018  (reads, like the filter, between appends)
    assert kept.dropped > 250 and kept.dropped + kept.n == t.size
    assert kept._t.size == 16  # never grew: the old rows made room
    rows = slice(kept.dropped, t.size)
    np.testing.assert_array_equal(kept.t_ns, full.t_ns[rows])
    np.testing.assert_array_equal(kept.gyro_B, full.gyro_B[rows])
    np.testing.assert_array_equal(kept.accel_B, full.accel_B[rows])
    np.testing.assert_array_equal(kept.alpha_B, full.alpha_B[rows])


def test_without_keep_from_nothing_is_dropped() -> None:
    t, g, a = _samples(40)
    h = ImuHistory(capacity=8)
    for k in range(t.size):
        h.append(int(t[k]), g[k], a[k])
    assert h.dropped == 0 and h.n == 40


def _run(ds: Any, config: Any) -> tuple[Any, ImuHistory]:
    init = groundtruth_start(ds, config, None) if config.init.mode == "groundtruth" else None
    nav = Navigator(config, rig_from_dataset(ds), initial_state=init)
    for t, kind, payload in measurements(ds, config, int(ds.imu.t_ns[0])):
        feed(nav, kind, t, payload)
    return nav.close(), nav.history


@pytest.mark.realdata  # EuRoC micro
def test_a_run_that_lets_samples_go_equals_the_full_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    case = next(c for c in CASES if c.name == "euroc_3d")
    ds = load_case_dataset(case, tmp_path)
    cfg = case_options(case, ds)
    full, full_history = _run(ds, cfg)
    assert full_history.dropped == 0  # 4.6 s: the default 60 s keeps everything
    monkeypatch.setattr(navigator_module, "ImuHistory", partial(ImuHistory, capacity=64))
    short = replace(cfg, buffer=replace(cfg.buffer, imu_keep_s=0.1))
    bounded, history = _run(ds, short)
    assert history.dropped > 300
    assert history._t.size <= 512  # ~1 s kept (faults.gap_spread_s), not the whole recording
    np.testing.assert_array_equal(bounded.t_ns, full.t_ns)
    np.testing.assert_array_equal(bounded.x, full.x)
    np.testing.assert_array_equal(bounded.P9, full.P9)
