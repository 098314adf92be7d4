"""Estimator: exact propagation to event times and the vision-updater extension point."""

from __future__ import annotations

import re

import numpy as np
import pytest

from _ins_truth import make_dataset, static_dataset, truth
from _nav_feed import run_with_updater
from svains.errors import ConfigError, FilterError
from svains.evaluation.run import run_method  # navigation run + accuracy keys
from svains.geometry.rotation import quat_box_minus
from svains.models.gps import gps_position
from svains.models.state import BIASED
from svains.navigation.base import FrameContext, MeasurementBlock, VisionUpdater
from svains.navigation.init import initialise
from svains.navigation.ins import InsFilter
from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions, RunOptions
from svains.replay import replay
from svains.replay.replay import groundtruth_start, history_from_dataset, rig_from_dataset

GT_INIT = InitOptions(mode="groundtruth")


def test_propagation_reaches_times_between_imu_samples_exactly() -> None:
    ds = make_dataset(4.0, noise_scale=1e-4)  # almost noise-free, biases ~0
    init = initialise(ds, BIASED, GT_INIT)
    # Tiny uncertainty: the UKF mean then is the noise-free propagation (a wide attitude
    # uncertainty would rightly shrink the mean specific force by E[cos δθ]).
    init.P *= 1e-8
    ins = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), BIASED, init, FilterOptions(),
                    NoiseOptions())
    t_mid = int(1.2345678e9)  # between two 100 Hz samples
    ins.propagate_to(t_mid)
    tr = truth(np.array([t_mid * 1e-9]))
    np.testing.assert_allclose(ins.ukf.x[0:3], tr["p"][0], atol=2e-4)
    np.testing.assert_allclose(ins.ukf.x[3:6], tr["v"][0], atol=5e-5)
    assert np.linalg.norm(quat_box_minus(tr["q"][0], ins.ukf.x[6:10])) < 1e-4
    # Stopping at t_mid on the way changes the end state only by the interpolation error.
    ins.propagate_to(int(3e9))
    other = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), BIASED, init,
                      FilterOptions(), NoiseOptions())
    other.propagate_to(int(3e9))
    np.testing.assert_allclose(ins.ukf.x[0:6], other.ukf.x[0:6], atol=1e-4)
    with pytest.raises(FilterError, match="cannot propagate backwards"):
        ins.propagate_to(int(2e9))
    with pytest.raises(FilterError, match="after the last IMU sample"):
        ins.propagate_to(int(10e9))


class _FixUpdater:
    """A stand-in vision method: at each frame it fuses the true position (a 'fix')."""

    method = "3d"

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
    u = _FixUpdater(ds, stack)
    opts = RunOptions(method="3d", init=GT_INIT, filter=FilterOptions(stack_with_vision=stack))
    res = run_with_updater(monkeypatch, ds, opts, u, u.times,
                           groundtruth_start(ds, opts, None))  # fmt: skip
    rep = res.report
    assert isinstance(u, VisionUpdater)
    frames = u.times[u.times <= ds.imu.t_ns[-1]]
    assert [c[0] for c in u.calls] == frames.tolist()
    assert [c[1] for c in u.calls] == [None, *frames[:-1].tolist()]
    assert rep["measurements"]["3d"]["fused"] == len(frames)
    n_stacked = sum(c[2] for c in u.calls)
    assert n_stacked == (3 if stack else 0)
    assert rep["measurements"]["gps"]["fused"] == 9 - n_stacked
    from svains.evaluation.run import run_accuracy

    assert run_accuracy(res, ds)["position_rmse_m"] < 0.1  # 1 cm fixes at 2.5 Hz


def test_unknown_method_and_model_are_refused() -> None:
    ds = make_dataset(2.0)
    with pytest.raises(ConfigError, match="method must be ins, vo, lc, tc or 3d, got 'nope'"):
        run_method(ds, "nope", RunOptions(init=GT_INIT))
    with pytest.raises(ConfigError, match="model must be paper or biased, got 'x'"):
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


def test_navigation_report_has_no_accuracy_keys_and_says_what_fixes_the_frame(tmp_path) -> None:
    # Layering: the estimator knows no ground-truth metrics; evaluation adds them.
    ds = make_dataset(3.0)
    res = replay(ds, RunOptions(init=GT_INIT))
    assert "ate_rmse_m" not in res.report and "position_rmse_m" not in res.report
    assert res.report["wall_s"] > 0 and res.report["measurements"]["gps"]["fused"] >= 2
    assert res.world_frame == "groundtruth" and res.gps_used and res.has_covariance
    static = replay(static_dataset()[0], RunOptions())
    assert static.world_frame == "local" and not static.gps_used  # no GPS in it
    no_gt = replay(ds, RunOptions(init=GT_INIT, use_gps=False))
    assert no_gt.world_frame == "groundtruth" and not no_gt.gps_used


def test_accuracy_report_survives_a_straight_trajectory() -> None:
    # A straight line leaves the rotation about itself undetermined: evo's se3 (Umeyama) fit
    # raises on it; the report falls back to fewer degrees of freedom and says which.
    from svains.datasets.types import GroundTruth
    from svains.evaluation.accuracy import accuracy_report

    n = 50
    t_ns = (np.arange(n) * 1e8).astype(np.int64)
    p = np.column_stack([np.linspace(0.0, 10.0, n), np.zeros(n), np.full(n, 2.0)])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    v = np.tile([2.0, 0.0, 0.0], (n, 1))
    gt = GroundTruth(t_ns, p, q, v, np.zeros((n, 3)), np.zeros((n, 3)))
    x = np.zeros((n, 13))
    x[:, 0:3] = p + np.array([0.3, 0.0, 0.0])
    x[:, 3:6], x[:, 6:10] = v, q
    rep = accuracy_report(t_ns, x, np.tile(np.eye(9), (n, 1, 1)), gt)
    assert rep["alignment"] == "posyaw"
    assert rep["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)  # a pure translation is aligned
    assert rep["position_rmse_m"] == pytest.approx(0.3)
    # Two poses only (se3 needs three): the fallback applies too.
    rep2 = accuracy_report(t_ns[:2], x[:2], np.tile(np.eye(9), (2, 1, 1)), gt)
    assert rep2["alignment"] == "posyaw" and rep2["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_outage_max_error_reported_per_gps_outage() -> None:
    ds = make_dataset(20.0, seed=2, outages=((6.0, 12.0),))
    rep = run_method(ds, "ins", RunOptions(init=GT_INIT)).report
    (outage,) = rep["gps_outages"]
    assert rep["outage_max_error_m"] == [outage["error_max_m"]]
    assert 0.0 < rep["outage_max_error_m"][0] < 2.3  # measured 1.54 m (2026-12-02), 1.5x
    assert "vision" not in rep  # ins has no vision counters


def test_paper_model_vision_update_sees_omega_white_noise(monkeypatch: pytest.MonkeyPatch) -> None:
    # The paper model's ω̂ carries the gyro's white noise (stencil anchor, 0.875 σ²/h): a vision
    # update, whose rotation model uses ω, must see it in P; GPS updates and P between frames not.
    from svains.models.state import DW

    ds = make_dataset(6.0, seed=4, noise_scale=20.0)
    seen: list[float] = []

    class _Probe:
        method = "3d"

        def update(self, ctx: FrameContext):
            seen.append(float(np.diag(ctx.ukf.P)[DW].min()))
            return None

    opts = RunOptions(method="3d", model="paper", init=GT_INIT)
    times = (np.arange(1.0, 5.0, 0.5) * 1e9).astype(np.int64) + 7
    res = run_with_updater(monkeypatch, ds, opts, _Probe(), times,
                           groundtruth_start(ds, opts, None))  # fmt: skip
    white = 0.875 * (2e-4 * 20.0) ** 2 / 0.01
    assert len(seen) == 8 and min(seen) >= white
    # The logged ω deviations include it too (the logged std is of ω̂ − ω).
    assert res.std[:, DW].min() ** 2 >= white


def test_paper_model_vision_update_treats_omega_white_noise_as_measurement_noise() -> None:
    from svains.models.state import DW, PAPER

    ds = make_dataset(3.0, seed=4, noise_scale=20.0)
    ins = InsFilter(history_from_dataset(ds), rig_from_dataset(ds), PAPER,
                    initialise(ds, PAPER, GT_INIT), FilterOptions(), NoiseOptions())
    ins.propagate_to(int(1e9))
    P_w = np.diag(ins.ukf.P)[DW].copy()
    white = ins.omega_white
    assert white > 5 * P_w.max()  # the white part dominates ω's uncertainty here
    w0 = ins.ukf.x[10:13].copy()
    ins.add_omega_white()  # what the runner does before a vision updater runs
    assert np.allclose(np.diag(ins.ukf.P)[DW], P_w + white)
    block = MeasurementBlock("omega", lambda X: X[:, 10:13], w0 + 0.1, np.full(3, 1e-6))
    ins.apply([block])
    ins.remove_omega_white()  # no-op: the update consumed it
    # As a state error the whole 0.1 rad/s would be "corrected"; as measurement noise only the
    # persistent part's share P/(P + W) is.
    shift = ins.ukf.x[10:13] - w0
    np.testing.assert_allclose(shift, 0.1 * P_w / (P_w + white + 1e-6), rtol=0.05)
    assert np.all(np.diag(ins.ukf.P)[DW] < P_w)


@pytest.mark.parametrize("missing", ["right", "left"])
def test_a_rig_with_one_camera_is_told_that_vision_is_stereo(euroc_micro, missing: str) -> None:  # type: ignore[no-untyped-def]
    """A left camera and an IMU (a user's probe): the refusal spoke of stereo pairs only."""
    from dataclasses import replace as with_fields

    from svains.datasets import load_dataset
    from svains.errors import DatasetError
    from svains.navigation.options import VisionOptions

    ds = with_fields(load_dataset(euroc_micro), **{missing: None})
    side = "cam1 (right)" if missing == "right" else "cam0 (left)"
    with pytest.raises(DatasetError, match=rf"0 stereo pair\(s\) with images on disk; image-"
                       rf"based vision needs at least 2: no {re.escape(side)} images; svains's "
                       r"vision is stereo \(without a second camera use --method ins\)$"):
        replay(ds, RunOptions(method="3d", vision=VisionOptions(source="images")))
