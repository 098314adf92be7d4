"""IMU faults injected into a simulated 30 s GPS-aided flight: does the filter survive?

Plain script (not a timed test). It simulates a 30 s village flight (GPS at 1 Hz without
outages, magnetometer, sonar, features0), writes one modified copy of the data set per fault
class of issue 12 into a temporary folder, runs ``ins`` and ``3d`` on each through the public
library entry (``svains.evaluation.run.run_method``, started from the ground truth) and prints:

- the position RMSE against ground truth, and its ratio to the clean run's (targets: ins <= 2x,
  3d <= 1.5x);
- the measurements rejected by the gates, and the filter's recoveries (``recovery.resets`` /
  ``recovery.inflations`` in ``report.json``, "-" when ``faults.consistency`` is off);
- the mean NEES (9 dof) after the fault (target <= 10);
- how long after the fault's end GPS fixes are accepted again (target <= 5 s).

    python bench/faults.py [--seed 0] [--at 10] [--methods ins,3d] [--guard]

The Navigator checks every IMU sample itself (``RunConfig.faults``); ``--guard`` also leaves the
samples a separate ``ImuGuard`` drops out of the faulty copy (it changes nothing now, kept to
compare with the figures taken before the guard was wired in).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset
from svains.datasets.asl_writer import AslWriter
from svains.datasets.types import Dataset, ImuStream
from svains.evaluation.run import run_method
from svains.navigation.imu_guard import ImuGuard
from svains.navigation.options import InitOptions, RunOptions
from svains.navigation.outputs import RunResult
from svains.replay.groundtruth import nees_series
from svains.sim import SimConfig, simulate

G0 = 9.80665
S = 1_000_000_000


@dataclass(frozen=True)
class Fault:
    """A fault class: its name, how long it lasts (s) and how it edits (t_ns, gyro, accel)."""

    name: str
    duration_s: float
    inject: Callable[[np.ndarray, np.ndarray, np.ndarray, int], np.ndarray]  # -> kept mask


def _spike_accel(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    a[k] = [1000.0, 0.0, 0.0]
    return np.ones(t.size, bool)


def _saturate(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    a[k : k + 3, 2] = 16 * G0
    return np.ones(t.size, bool)


def _spike_gyro(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    g[k, 0] = 35.0
    return np.ones(t.size, bool)


def _zeros(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    bad = (t >= t[k]) & (t < t[k] + S)
    g[bad], a[bad] = 0.0, 0.0
    return np.ones(t.size, bool)


def _gap(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    return ~((t >= t[k]) & (t < t[k] + 5 * S))


FAULTS = (
    Fault("clean", 0.0, lambda t, g, a, k: np.ones(t.size, bool)),
    Fault("accel 1000 m/s² x1", 0.0, _spike_accel),
    Fault("accel 16 g x3", 0.03, _saturate),
    Fault("gyro 35 rad/s x1", 0.0, _spike_gyro),
    Fault("zeros 1 s", 1.0, _zeros),
    Fault("gap 5 s", 5.0, _gap),
)


def faulty_copy(clean: Path, fault: Fault, at_s: float, out: Path, guard: bool) -> Path:
    """Copy the data set at ``clean`` to ``out`` with ``fault`` injected into imu0 at ``at_s``;
    with ``guard``, the samples :class:`ImuGuard` drops are left out of the copy (what the
    wired guard will do, minus the covariance inflation over gaps)."""
    shutil.copytree(clean, out)
    ds = load_dataset(clean)
    assert ds.imu is not None and ds.imu_calib is not None
    t, g, a = ds.imu.t_ns.copy(), ds.imu.gyro_B.copy(), ds.imu.accel_B.copy()
    k = int(np.searchsorted(t, int(at_s * S)))
    keep = fault.inject(t, g, a, k)
    if guard:
        imu_guard = ImuGuard.from_calib(ds.imu_calib)
        keep &= np.array([imu_guard.check(int(ti), gi, ai).accepted
                          for ti, gi, ai in zip(t, g, a, strict=True)])  # fmt: skip
    AslWriter(out).write_imu(ImuStream(t[keep], g[keep], a[keep]), ds.imu_calib)
    return out


def gps_back_after_s(ds: Dataset, res: RunResult, fault_end_ns: int) -> float | None:
    """Seconds from ``fault_end_ns`` to the first accepted GPS fix at or after it (None: never).

    The run's GPS updates come in the order of the fixes it fused (one per fix inside its
    span), so the k-th ``gps`` update is the k-th fix after the start.
    """
    assert ds.gps is not None
    stats = [u for u in res.updates if u.name == "gps"]
    t_fix = ds.gps.t_ns[(ds.gps.t_ns > res.t_ns[0]) & (ds.gps.t_ns <= res.t_ns[-1])]
    if len(stats) != t_fix.size:
        return None
    ok = [t for t, u in zip(t_fix, stats, strict=True) if u.accepted and t >= fault_end_ns]
    return (int(ok[0]) - fault_end_ns) / S if ok else None


def row(ds: Dataset, res: RunResult, clean_rmse: float | None, at_s: float, fault: Fault) -> str:
    rep = res.report
    rmse = rep["position_rmse_m"]
    ratio = f"{rmse / clean_rmse:.2f}" if clean_rmse else "1.00"
    rejected = sum(c["rejected"] for c in rep.get("measurements", {}).values())
    recovery = rep.get("recovery")
    resets = (
        f"{recovery.get('resets', 0)}/{recovery.get('inflations', 0)}" if recovery else "-"
    )
    end_ns = int((at_s + fault.duration_s) * S)
    assert ds.groundtruth is not None
    t, nees = nees_series(res.t_ns, res.x, res.P9, ds.groundtruth)
    after = nees[t >= end_ns]
    back = gps_back_after_s(ds, res, end_ns)
    back_txt = "never" if back is None else f"{back:.1f}"
    return (
        f"| {fault.name} | {rep['method']} | {rmse:.3f} | {ratio} | {rejected} | {resets} | "
        f"{after.mean():.3g} | {back_txt} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--at", type=float, default=10.0, help="fault time (s from the start)")
    ap.add_argument("--methods", default="ins,3d")
    ap.add_argument("--guard", action="store_true",
                    help="drop the samples ImuGuard rejects before the run (a preview of item 1)")
    args = ap.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    cfg = SimConfig(duration_s=30.0, seed=args.seed)
    cfg.camera.render_images = False
    cfg.gps.outages = []
    options = RunOptions(init=InitOptions(mode="groundtruth"))
    print("| fault | method | pos RMSE [m] | x clean | rejected | resets/inflations | "
          "NEES after | GPS back after [s] |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        clean = simulate(cfg, Path(tmp) / "clean")
        clean_rmse: dict[str, float] = {}
        for i, fault in enumerate(FAULTS):
            root = faulty_copy(clean, fault, args.at, Path(tmp) / f"fault{i}", args.guard)
            ds = load_dataset(root)
            for method in methods:
                res = run_method(ds, method, options)
                if fault.name == "clean":
                    clean_rmse[method] = float(res.report["position_rmse_m"])
                print(row(ds, res, clean_rmse.get(method), args.at, fault), flush=True)


if __name__ == "__main__":
    main()
