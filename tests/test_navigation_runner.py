"""Runner: exact propagation to event times and the vision-updater extension point."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from _ins_truth import make_dataset, static_dataset, truth
from svains.errors import ConfigError, FilterError
from svains.geometry.rotation import quat_box_minus
from svains.models.gps import gps_position
from svains.models.state import BIASED
from svains.navigation import base
from svains.navigation.base import FrameContext, MeasurementBlock, VisionUpdater
from svains.navigation.init import initialise
from svains.navigation.ins import InsFilter
from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions, RunOptions
from svains.navigation.runner import run_method

GT_INIT = InitOptions(mode="groundtruth")


def test_propagation_reaches_times_between_imu_samples_exactly() -> None:
    ds = make_dataset(4.0, noise_scale=1e-4)  # almost noise-free, biases ~0
    init = initialise(ds, BIASED, GT_INIT)
    # Tiny uncertainty: the UKF mean then is the noise-free propagation (a wide attitude
    # uncertainty would rightly shrink the mean specific force by E[cos δθ]).
    init.P *= 1e-8
    ins = InsFilter(ds, BIASED, init, FilterOptions(), NoiseOptions())
    t_mid = int(1.2345678e9)  # between two 100 Hz samples
    ins.propagate_to(t_mid)
    tr = truth(np.array([t_mid * 1e-9]))
    np.testing.assert_allclose(ins.ukf.x[0:3], tr["p"][0], atol=2e-4)
    np.testing.assert_allclose(ins.ukf.x[3:6], tr["v"][0], atol=5e-5)
    assert np.linalg.norm(quat_box_minus(tr["q"][0], ins.ukf.x[6:10])) < 1e-4
    # Stopping at t_mid on the way changes the end state only by the interpolation error.
    ins.propagate_to(int(3e9))
    other = InsFilter(ds, BIASED, init, FilterOptions(), NoiseOptions())
    other.propagate_to(int(3e9))
    np.testing.assert_allclose(ins.ukf.x[0:6], other.ukf.x[0:6], atol=1e-4)
    with pytest.raises(FilterError, match="cannot propagate backwards"):
        ins.propagate_to(int(2e9))
    with pytest.raises(FilterError, match="after the last IMU sample"):
        ins.propagate_to(int(10e9))


class _FixUpdater:
    """A stand-in vision method: at each frame it fuses the true position (a 'fix')."""

    method = "dummy"

    def __init__(self, ds, stack: bool) -> None:
        self.ds = ds
        self.times = (np.arange(0.5, 9.5, 0.4) * 1e9).astype(np.int64) + 1_234_567
        if stack:  # put some frames exactly on GPS times so stacking happens
            self.times = np.unique(np.r_[self.times, ds.gps.t_ns[2:5]])
        self.calls: list[tuple[int, int | None, int]] = []

    def frame_times(self) -> np.ndarray:
        return self.times

    def update(self, ctx: FrameContext):
        tr = truth(np.array([ctx.t_ns * 1e-9]))
        block = MeasurementBlock(
            "fix", lambda X: gps_position(X, np.zeros(3)), tr["p"][0], np.full(3, 0.01**2)
        )
        self.calls.append((ctx.t_ns, ctx.t_prev_ns, len(ctx.extra)))
        return ctx.apply([block, *ctx.extra])


@pytest.mark.parametrize("stack", [False, True])
def test_vision_updater_protocol(monkeypatch: pytest.MonkeyPatch, stack: bool) -> None:
    ds = make_dataset(10.0, seed=4)
    holder: dict[str, _FixUpdater] = {}

    def make_updater(dataset, options):
        holder["u"] = _FixUpdater(dataset, stack)
        return holder["u"]

    mod = types.ModuleType("svains_fake_vision")
    mod.make_updater = make_updater  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "svains_fake_vision", mod)
    monkeypatch.setitem(base.VISION_METHOD_MODULES, "dummy", "svains_fake_vision")
    opts = RunOptions(init=GT_INIT, filter=FilterOptions(stack_with_vision=stack))
    rep = run_method(ds, "dummy", opts).report
    u = holder["u"]
    assert isinstance(u, VisionUpdater)
    frames = u.times[u.times <= ds.imu.t_ns[-1]]
    assert [c[0] for c in u.calls] == frames.tolist()
    assert [c[1] for c in u.calls] == [None, *frames[:-1].tolist()]
    assert rep["measurements"]["dummy"]["fused"] == len(frames)
    n_stacked = sum(c[2] for c in u.calls)
    assert n_stacked == (3 if stack else 0)
    assert rep["measurements"]["gps"]["fused"] == 9 - n_stacked
    assert rep["method"] == "dummy"
    assert rep["position_rmse_m"] < 0.1  # 1 cm fixes at 2.5 Hz


def test_unknown_method_and_model_are_refused() -> None:
    ds = make_dataset(2.0)
    with pytest.raises(ConfigError, match="unknown method 'nope'"):
        run_method(ds, "nope", RunOptions(init=GT_INIT))
    with pytest.raises(ConfigError, match="unknown model 'x'"):
        run_method(ds, "ins", RunOptions(model="x", init=GT_INIT))  # type: ignore[arg-type]


def test_progress_callback_reaches_one() -> None:
    seen: list[float] = []
    run_method(make_dataset(3.0), "ins", RunOptions(init=GT_INIT), progress=seen.append)
    assert seen[-1] == 1.0 and seen == sorted(seen) and len(seen) > 2


def test_run_without_ground_truth_reports_none_and_writes_outputs(tmp_path) -> None:
    ds, _ = static_dataset()
    res = run_method(ds, "ins", RunOptions(), out_dir=tmp_path)
    rep = res.report
    assert rep["ate_rmse_m"] is None and rep["nees_mean"] is None
    assert rep["measurements"]["mag"]["fused"] > 20
    # Static: the estimate stays put (velocity near zero after 3 s of IMU + magnetometer).
    assert np.linalg.norm(res.x[-1, 3:6]) < 0.2
    assert (tmp_path / "report.json").is_file() and (tmp_path / "states.csv").is_file()
