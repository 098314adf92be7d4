"""Forward-backward smoothing of a navigation run (``smoother.enabled``, ``svains run --smooth``).

The filter records its history as it runs (``filter.rts.RtsRecorder`` on the ``UKF``, created
by :func:`history_recorder`); after the run, :func:`smoothed_result` runs the backward
Rauch-Tung-Striebel pass and returns the smoothed estimates as a ``RunResult`` at the forward
run's output times, so the same accuracy keys and writers apply.

Kept per output state: the (δp, δv, δθ) rows (9), which give the pose, velocity and their
covariance. The other rows (ω, the IMU biases) are kept on the whole-state epochs only, every
``smoother.chain_interval_s``: the smoothed bias correction between two of them is interpolated
(biases are random walks: over a second they barely move), ω keeps the forward value, and the
standard deviations of ω and the biases are the forward ones.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from svains.errors import ConfigError
from svains.filter.rts import RtsRecorder, smooth
from svains.models.manifold import NavManifold
from svains.models.state import DBA, DBG, DTH, StateLayout
from svains.navigation.heading_wait import forward_in_old_frames, turn_smoothed
from svains.navigation.outputs import RunResult

if TYPE_CHECKING:
    from svains.navigation.ins import InsFilter
    from svains.navigation.options import RunConfig

OUTPUT_ROWS = np.arange(DTH.stop)  # δp, δv, δθ


def history_recorder(config: RunConfig, ins: InsFilter) -> RtsRecorder:
    """A recorder attached to ``ins``'s UKF from its current state on."""
    # The forward means are in the run's own log: the recorder keeps none (``keep_x=0``).
    rec = RtsRecorder(OUTPUT_ROWS, 0, int(config.smoother.chain_interval_s * 1e9))
    rec.start(ins.ukf.x, ins.ukf.P)
    ins.ukf.recorder = rec
    return rec


def smoothed_result(result: RunResult) -> RunResult:
    """The smoothed estimates of ``result`` (a run made with ``smoother.enabled``): the same
    times, ``x``, ``std``, ``P9``; its ``report`` holds the forward run's identification keys
    (``method``, GPS-off windows) and ``smoothing`` (wall time, what was kept)."""
    if not isinstance(result, RunResult):
        raise TypeError(f"smoothed_result takes the RunResult of a finished run (Navigator."
                        f"close()), got {type(result).__name__}")  # fmt: skip
    if "smoothing" in result.report:
        raise ConfigError("this RunResult is smoothed already: smooth the forward run's "
                          "RunResult (Navigator.close())")  # fmt: skip
    rec = result.history
    if rec is not None and rec.considered:
        raise ConfigError("the run carried consider parameters, which the backward pass does "
                          "not handle (it can end worse than the forward run): not smoothed")
    if rec is None:
        raise ConfigError("the run kept no history to smooth: run it with smoother.enabled "
                          "(svains run --smooth)")  # fmt: skip
    t0 = time.perf_counter()
    s = smooth(rec)
    layout = StateLayout(biased=result.x.shape[1] >= 19)
    nav = NavManifold(layout)
    if not np.array_equal(s.t_ns, result.t_ns):
        raise ConfigError("the history's epochs are not the run's output times")
    dX = np.zeros((len(s.t_ns), layout.ndx))
    dX[:, OUTPUT_ROWS] = s.eps
    std = np.array(result.std, dtype=float, copy=True)
    std[:, OUTPUT_ROWS] = np.sqrt(np.maximum(np.diagonal(s.P, axis1=1, axis2=2), 0.0))
    if layout.biased:
        # The navigation block leads every whole-state epoch, whatever follows it.
        nav_eps = np.array([e[: layout.ndx] for e in s.chain_eps])
        for j in (*range(DBG.start, DBG.stop), *range(DBA.start, DBA.stop)):
            dX[:, j] = np.interp(s.t_ns, s.chain_t_ns, nav_eps[:, j])
    # Estimates logged before a frame turn (a local start's heading found) were smoothed in
    # the frame they were made in: corrected there, then turned with the turn's uncertainty.
    turns = result.frame_turns
    x_fwd = (forward_in_old_frames(result.x, result.t_ns, turns) if turns
             else np.asarray(result.x, dtype=float))  # fmt: skip
    x = nav.retract(x_fwd, dX)
    P9 = np.array(s.P)
    if turns:
        turn_smoothed(x, std, P9, result.t_ns, turns)
    wall = time.perf_counter() - t0
    duration_s = max((int(s.t_ns[-1]) - int(s.t_ns[0])) * 1e-9, 1e-9) if len(s.t_ns) else 0.0
    mb = rec.nbytes / 1e6
    # what the accuracy keys read of the run: its methods, its GPS-off windows, and what was
    # fused and how it started (whether its first state anchors the frame: without them a
    # run that fused magnetometer and sonar read 13x overconfident, anchored: a user's probe)
    keep = ("method", "model", "gps_off_windows_ns", "measurements", "init")
    report = {k: result.report[k] for k in keep if k in result.report}
    report["smoothing"] = {
        "wall_s": wall,
        "history_mb": mb,
        # per hour from 10 s of data or more (a 1 s run's fixed part read as 2.8e10 MB an
        # hour: a user's probe)
        "history_mb_per_hour": mb * 3600.0 / duration_s if duration_s >= 10.0 else None,
        "epochs_kept": len(s.t_ns),
        "whole_state_epochs": len(s.chain_t_ns),
        "updates_composed": rec.updates,
        "chain_cuts": rec.cuts,
    }
    return replace(result, x=x, std=std, P9=P9, report=report, history=None,
                   updates=[], update_log=[], tracks=None)  # fmt: skip
