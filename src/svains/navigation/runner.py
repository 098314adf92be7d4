"""``run_method``: run one navigation method over a data set, write its outputs.

The result carries what the navigation knows (estimates, covariances, timings, counters, what
anchors its world frame); accuracy against ground truth is added above this layer, by
:func:`svains.evaluation.run.run_method` (what ``svains run`` calls).

Events (IMU-propagated to their exact time, ties in this order): GPS, magnetometer, sonar, vision
frame, output tick. Output ticks every ``RunOptions.output_period_s`` (default 20 Hz) plus the
last IMU time fill ``states.csv`` and ``trajectory.tum``.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from svains.datasets.types import Dataset
from svains.errors import ConfigError
from svains.filter.ukf import UpdateStats
from svains.models.state import BIASED, PAPER
from svains.navigation.base import VISION_METHOD_MODULES, FrameContext, MeasurementBlock
from svains.navigation.init import initialise
from svains.navigation.ins import InsFilter
from svains.navigation.options import RunOptions
from svains.navigation.writers import write_outputs

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
ProgressFn = Callable[[float], None]
log = logging.getLogger(__name__)

_GPS, _MAG, _SONAR, _FRAME, _TICK = range(5)
_NAMES = {_GPS: "gps", _MAG: "mag", _SONAR: "sonar"}


WorldFrame = Literal["groundtruth", "gps", "local"]


@dataclass
class RunResult:
    """Logged estimates: ``t_ns`` (T,), ``x`` (T, nx), ``std`` (T, ndx) tangent std devs,
    ``P9`` (T, 9, 9) covariance of (p, v, δθ); ``report`` = the ``report.json`` content.

    ``world_frame`` says what ties the estimate's world frame to the ground truth's:
    ``groundtruth`` (initialised from it), ``gps`` (GPS fixes fused) or ``local`` (static start
    without GPS: yaw and position are arbitrary, so raw errors against ground truth mean nothing).
    ``gps_used``: GPS was enabled and present; ``has_covariance``: False for filter-free methods.
    """

    t_ns: I64
    x: F64
    std: F64
    P9: F64
    report: dict[str, Any]
    updates: list[UpdateStats] = field(default_factory=list, repr=False)
    world_frame: WorldFrame = "groundtruth"
    gps_used: bool = False
    has_covariance: bool = True


def _events(ins: InsFilter, dataset: Dataset, options: RunOptions, frames: I64) -> F64:
    t0, t1 = ins.t_ns, ins.t_end_ns
    if options.duration_s is not None:
        t1 = min(t1, t0 + int(options.duration_s * 1e9))
    cols = []

    def add(t: I64, kind: int, max_rate_hz: float | None = None) -> None:
        t = np.asarray(t, dtype=np.int64)
        idx = np.arange(len(t))
        keep = (t > t0) & (t <= t1)
        if max_rate_hz is not None and len(t):
            # Keep the first sample of each 1/max_rate bin (bins anchored at 0 ns, so streams
            # sampled on the same clock keep the same instants).
            bins = t // int(1e9 / max_rate_hz)
            keep &= np.r_[True, bins[1:] != bins[:-1]]
        cols.append(np.stack([t[keep], np.full(keep.sum(), kind), idx[keep]], axis=1))

    if options.use_gps and dataset.gps is not None and dataset.gps_calib is not None:
        add(dataset.gps.t_ns, _GPS)
    if options.use_mag and dataset.mag is not None and dataset.mag_calib is not None:
        add(dataset.mag.t_ns, _MAG, options.max_mag_rate_hz)
    if options.use_sonar and dataset.sonar is not None and dataset.sonar_calib is not None:
        add(dataset.sonar.t_ns, _SONAR, options.max_sonar_rate_hz)
    add(frames, _FRAME)
    # Output ticks on a grid anchored at 0 ns (so they coincide with sensor samples on the same
    # clock), snapped to IMU sample times (no extra interpolated node, no short chunks).
    period = int(options.output_period_s * 1e9)
    grid = np.arange((t0 // period + 1) * period, t1, period, dtype=np.int64)
    ticks = np.unique(ins.t_imu[np.clip(np.searchsorted(ins.t_imu, grid), 0, len(ins.t_imu) - 1)])
    add(np.append(ticks[ticks < t1], t1), _TICK)
    ev = np.concatenate(cols)
    return ev[np.lexsort((ev[:, 1], ev[:, 0]))]


def _world_frame(init_mode: str, counts: dict[str, dict[str, int]]) -> WorldFrame:
    if init_mode == "groundtruth":
        return "groundtruth"
    # A static start sets roll and pitch from gravity only; GPS fixes tie position (and, through
    # the trajectory, yaw) to the world frame.
    return "gps" if counts.get("gps", {}).get("fused", 0) > 0 else "local"


def _make_updater(dataset: Dataset, method: str, options: RunOptions) -> Any:
    if method not in VISION_METHOD_MODULES:
        raise ConfigError(
            f"unknown method {method!r}; known: ins, {', '.join(VISION_METHOD_MODULES)}"
        )
    module = importlib.import_module(VISION_METHOD_MODULES[method])
    return module


def run_method(
    dataset: Dataset,
    method: str = "ins",
    options: RunOptions | None = None,
    out_dir: Path | None = None,
    progress: ProgressFn | None = None,
) -> RunResult:
    """Run ``method`` ("ins" or a vision method) over ``dataset``; write outputs to ``out_dir``.

    The report holds the run's own figures (timings, counters, initialisation) but no accuracy
    keys: :func:`svains.evaluation.run.run_method` adds those and writes the outputs.

    ``progress(fraction)`` is called now and then with the fraction of data processed.
    """
    options = options or RunOptions()
    if options.model not in ("paper", "biased"):
        raise ConfigError(f"unknown model {options.model!r} (paper|biased)")
    updater = None
    wall0 = time.perf_counter()  # includes the vision method's set-up (its front end)
    if method != "ins":
        module = _make_updater(dataset, method, options)
        if not hasattr(module, "make_updater"):
            # Filter-free method (vo): it writes its own outputs into ``out_dir``.
            return module.run(dataset, options, progress, out_dir=out_dir)  # type: ignore[no-any-return]
        updater = module.make_updater(dataset, options)
    layout = BIASED if options.model == "biased" else PAPER
    init = initialise(dataset, layout, options.init)
    ins = InsFilter(dataset, layout, init, options.filter, options.noise)
    frames = np.zeros(0, np.int64) if updater is None else np.asarray(updater.frame_times())
    events = _events(ins, dataset, options, frames)
    frame_set = set(frames.tolist()) if options.filter.stack_with_vision else set()
    gate = options.filter.gate_probability
    counts: dict[str, dict[str, int]] = {}
    updates: list[UpdateStats] = []
    log_t, log_x, log_std, log_P9 = [ins.t_ns], [ins.ukf.x[: layout.nx].copy()], [], []
    log_std.append(ins.tangent_std())
    log_P9.append(ins.ukf.P[:9, :9].copy())
    t_prev_frame: int | None = None

    def count(stats: UpdateStats, key: str) -> None:
        c = counts.setdefault(key, {"fused": 0, "rejected": 0})
        c["fused" if stats.accepted else "rejected"] += 1
        updates.append(stats)

    def apply(blocks: list[MeasurementBlock]) -> UpdateStats:
        return ins.apply(blocks, gate)

    n_ev = len(events)
    next_report = 0
    e = 0
    while e < n_ev:
        t = int(events[e, 0])
        e_end = e
        while e_end < n_ev and events[e_end, 0] == t:
            e_end += 1
        ins.propagate_to(t)
        blocks: list[MeasurementBlock] = []
        has_frame = has_tick = False
        for _, kind, i in events[e:e_end]:
            if kind == _GPS:
                blocks.append(ins.gps_block(int(i), options.use_gps_velocity))
            elif kind == _MAG:
                blocks.append(ins.mag_block(int(i)))
            elif kind == _SONAR:
                blocks.append(ins.sonar_block(int(i)))
            elif kind == _FRAME:
                has_frame = True
            else:
                has_tick = True
        if blocks and not (has_frame and t in frame_set):
            # Simultaneous measurements: one sigma-point draw, each gated on its own.
            for stats in ins.ukf.update_blocks(
                [(b.h, b.z, b.R, b.residual, b.name) for b in blocks], gate
            ):
                count(stats, stats.name)
            blocks = []
        if has_frame:
            assert updater is not None
            ctx = FrameContext(ins.ukf, layout, t, t_prev_frame, gate, blocks, apply)
            ins.add_omega_white()  # paper model: the vision models see ω's gyro white noise
            stats = updater.update(ctx)
            ins.remove_omega_white()
            if hasattr(updater, "after_frame"):
                updater.after_frame(ctx)  # pose clones (rotation="clone")
            if stats is not None:
                count(stats, method)
            t_prev_frame = t
        if has_tick:
            log_t.append(t)
            log_x.append(ins.ukf.x[: layout.nx].copy())
            log_std.append(ins.tangent_std())
            log_P9.append(ins.ukf.P[:9, :9].copy())
        e = e_end
        if progress is not None and e >= next_report:
            progress(e / max(1, n_ev))
            next_report = e + max(1, n_ev // 200)
    if progress is not None:
        progress(1.0)
    wall = time.perf_counter() - wall0
    result = RunResult(
        np.array(log_t, dtype=np.int64),
        np.array(log_x),
        np.array(log_std),
        np.array(log_P9),
        {},
        updates,
        world_frame=_world_frame(str(init.info.get("mode")), counts),
        gps_used=bool(options.use_gps and dataset.gps is not None),
    )
    duration = (result.t_ns[-1] - result.t_ns[0]) * 1e-9
    report: dict[str, Any] = {
        "method": method,
        "model": options.model,
        "dataset": dataset.name,
        "init": init.info,
        "wall_s": wall,
        "data_duration_s": duration,
        "realtime_factor": duration / wall if wall > 0 else None,
        "imu_steps": int(np.searchsorted(ins.t_imu, result.t_ns[-1], "right"))
        - int(np.searchsorted(ins.t_imu, result.t_ns[0])),
        "measurements": counts,
        "states_rate_hz": 1.0 / options.output_period_s,
    }
    if updater is not None and hasattr(updater, "summary"):
        # Vision counters: frames fused/rejected, features gated (see the updater's summary).
        report["vision"] = updater.summary()
    result.report = report
    if out_dir is not None:
        write_outputs(Path(out_dir), result, layout)
    return result
