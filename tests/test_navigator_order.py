"""The Navigator's time-ordered buffer: measurements delivered late within ``buffer.window_s``
give the in-order result bit for bit; later ones are dropped and counted."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _golden_cases import CASES, case_options, load_case_dataset
from svains.navigation.navigator import Navigator
from svains.navigation.options import BufferOptions
from svains.replay.replay import (
    _FRAME,
    _IMU,
    feed,
    groundtruth_start,
    measurements,
    rig_from_dataset,
)


def _run(ds: Any, config: Any, delay_ns: dict[int, Any]) -> Any:
    """Feed ``ds`` with each measurement of kind k delivered ``delay_ns[k](i)`` ns after its
    stamp (after the IMU samples up to then); returns the ``RunResult``."""
    events = list(measurements(ds, config, int(ds.imu.t_ns[0])))
    keyed = []
    for i, (t, kind, payload) in enumerate(events):
        d = int(delay_ns[kind](i)) if kind in delay_ns else 0
        # Delivered after every IMU sample stamped up to t + d.
        keyed.append(((t + d, 1 if kind != _IMU and d else 0, i), (t, kind, payload)))
    keyed.sort(key=lambda e: e[0])
    init = groundtruth_start(ds, config, None) if config.init.mode == "groundtruth" else None
    nav = Navigator(config, rig_from_dataset(ds), initial_state=init)
    for _, (t, kind, payload) in keyed:
        feed(nav, kind, t, payload)
    return nav.close()


def _case(name: str) -> Any:
    return next(c for c in CASES if c.name == name)


@pytest.fixture(scope="session")
def golden_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # The session's base folder, as tests/test_golden.py and tests/test_navigator.py use: the
    # 30 s village is simulated once per worker, not once per test.
    return tmp_path_factory.getbasetemp()


@pytest.mark.slow
@pytest.mark.realdata  # EuRoC micro's images
def test_images_60_ms_late_give_the_in_order_result(tmp_path: Path) -> None:
    case = _case("euroc_images_3d")
    ds = load_case_dataset(case, tmp_path)
    cfg = case_options(case, ds)
    assert cfg.buffer.window_s >= 0.06
    in_order = _run(ds, cfg, {})
    late = _run(ds, cfg, {_FRAME: lambda i: 60_000_000})
    assert late.report["measurements"] == in_order.report["measurements"]
    np.testing.assert_array_equal(late.t_ns, in_order.t_ns)
    np.testing.assert_array_equal(late.x, in_order.x)
    np.testing.assert_array_equal(late.P9, in_order.P9)
    assert "dropped" not in late.report


def test_jittered_gps_mag_sonar_within_the_window_change_nothing(golden_tmp: Path) -> None:
    case = _case("village_3d")
    ds = load_case_dataset(case, golden_tmp)
    cfg = replace(case_options(case, ds), duration_s=4.0)
    rng = np.random.default_rng(5)
    jitter = rng.integers(0, 90_000_000, 100_000)
    in_order = _run(ds, cfg, {})
    late = _run(ds, cfg, {k: (lambda i: jitter[i % jitter.size]) for k in range(4)})
    np.testing.assert_array_equal(late.x, in_order.x)
    assert late.report["measurements"] == in_order.report["measurements"]


def test_beyond_the_window_frames_are_dropped_and_counted(golden_tmp: Path) -> None:
    case = _case("village_3d")
    ds = load_case_dataset(case, golden_tmp)
    cfg = replace(case_options(case, ds), duration_s=8.0, buffer=BufferOptions(window_s=0.05))
    late = _run(ds, cfg, {_FRAME: lambda i: 60_000_000 if i % 2 else 0})
    in_order = _run(ds, cfg, {})
    n_late = late.report["dropped"]["frame"]
    assert n_late > 5
    assert (late.report["measurements"]["3d"]["fused"]
            < in_order.report["measurements"]["3d"]["fused"])  # fmt: skip
