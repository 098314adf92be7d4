"""Sensor faults injected into a simulated 30 s GPS-aided flight: does the filter survive?

Plain script (not a timed test). It simulates a 30 s village flight (GPS at 1 Hz without
outages, magnetometer, sonar, features0), writes one modified copy of the data set per fault
class into a temporary folder: the IMU classes of issue 12 (and a frozen output: the sample at
the fault repeated for 1 s; bias steps of +0.5 m/s² on the x accelerometer and +0.05 rad/s on
the z gyro, for the rest of the run); the classes of issue 23: a GPS step (every fix from the
fault on offset by 50 m east, to the end), a frozen GPS (the fix at the fault repeated for
10 s), GPS multipath (for 10 s each fix off by its own 10 m, 1 sigma per axis), a GPS
velocity 5 m/s off east (to the end; positions right), a GPS position ramp (1 m/s east for
10 s, velocities right), a magnetometer turned 8° about its z axis for 10 s (steel nearby),
a dead
magnetometer (zeros from the fault on), a bad sonar (5 s of negative ranges, every third one a
40 m false echo instead), and all at once (each IMU class in turn, 1.5 s apart, the 5 s gap
among them, with the frozen GPS, the dead magnetometer and the bad sonar;
not the persistent GPS step, which has its own row). "GPS lost" (no fix from the fault on) is
the reference the ``ins`` run under the GPS step is held to: with no other sensor to
contradict a step, its error must be no worse than without GPS; "GPS lost 10 s" is the frozen
GPS's, the multipath's and the ramp's (their fixes carry next to nothing); "data lost" is all
at once's: the data its faults destroy left out instead of corrupted (the bias steps, not a
loss of data, left out of it).

It runs ``ins`` and ``3d`` on each through the public library entry
(``svains.evaluation.run.run_method``, started from the ground truth) and prints:

- the position RMSE against ground truth, and its ratio to the clean run's (targets: ins <= 2x,
  3d <= 1.5x);
- the measurements rejected by the gates, and the filter's recoveries (``recovery.resets`` /
  ``recovery.inflations`` / ``recovery.bias_shifts``
  in ``report.json``, "-" when ``faults.consistency`` is off);
- the mean NEES (9 dof) after the fault (target <= 12), and its position, velocity and attitude
  blocks (3 dof each, each against its own 3x3 covariance: consistent blocks average 3);
- how long after the fault's end GPS fixes are accepted again (target <= 5 s).

    python bench/faults.py [--seeds 0] [--at 10] [--gap-s 5] [--faults "accel step,gap"]
                           [--methods ins,3d] [--guard]
                           [--set filter.alpha=0.5 ...]

``--seeds 0-7`` (or ``0,1``) runs every seed and ends with a table over the seeds: the mean NEES
after the fault and how many seeds exceed 10, the mean and largest RMSE ratio, the latest GPS
return. One run's NEES mean is one draw: its errors are correlated over tens of seconds (a
GPS-aided position error is an average of the last fixes' noise), so a consistent filter
exceeds 10 on a fair share of seeds; the mean over seeds is the consistency test. ``--set``
overrides run settings as ``svains run --set`` does (every run, clean ones included).
``--nees-window 10:12.5`` (repeatable; seconds from the start of the run) adds the mean NEES
(9 dof) over that window to each row and to the table over the seeds: "after the fault" starts
at the fault's end, which for all at once is the gyro bias step, the last of its classes.

The Navigator checks every IMU sample itself (``RunConfig.faults``); ``--guard`` also leaves the
samples a separate ``ImuGuard`` drops out of the faulty copy (it changes nothing now, kept to
compare with the figures taken before the guard was wired in).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset
from svains.datasets.asl_writer import AslWriter
from svains.datasets.types import Dataset, GpsStream, ImuStream, MagStream, SonarStream
from svains.evaluation.run import run_method
from svains.navigation.config_io import parse_setting, with_settings
from svains.navigation.imu_guard import ImuGuard
from svains.navigation.options import InitOptions, RunOptions
from svains.navigation.outputs import RunResult
from svains.replay.groundtruth import interpolate_groundtruth, navigation_errors, nees_of
from svains.sim import SimConfig, simulate

G0 = 9.80665
S = 1_000_000_000


@dataclass
class Streams:
    """The data set's streams a fault may edit in place: IMU (``keep`` marks the samples
    written back), GPS fixes, magnetometer and sonar samples (empty arrays when absent)."""

    t: np.ndarray
    g: np.ndarray
    a: np.ndarray
    keep: np.ndarray
    gps_t: np.ndarray
    gps_p: np.ndarray
    mag_t: np.ndarray
    mag_m: np.ndarray
    sonar_t: np.ndarray
    sonar_r: np.ndarray
    gps_v: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # per fix, if given


@dataclass(frozen=True)
class Fault:
    """A fault class: its name, how long it lasts (s; the figures "after" start at its end)
    and how it edits the streams from the fault time ``at_ns``."""

    name: str
    duration_s: float
    inject: Callable[[Streams, int], None]


def _imu(edit: Callable[[np.ndarray, np.ndarray, np.ndarray, int], np.ndarray]
         ) -> Callable[[Streams, int], None]:  # fmt: skip
    """An IMU edit of (t, gyro, accel, k) returning the kept mask, as a ``Fault.inject``."""

    def inject(st: Streams, at_ns: int) -> None:
        k = int(np.searchsorted(st.t, at_ns))
        st.keep &= edit(st.t, st.g, st.a, k)

    return inject


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


def _frozen(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    bad = (t >= t[k]) & (t < t[k] + S)  # the sample at k repeated for 1 s, with new stamps
    g[bad], a[bad] = g[k], a[k]
    return np.ones(t.size, bool)


def _accel_step(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    a[k:, 0] += 0.5  # a bias step (a knocked or overheated IMU) for the rest of the run
    return np.ones(t.size, bool)


def _gyro_step(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
    g[k:, 2] += 0.05
    return np.ones(t.size, bool)


def _gap(gap_s: float) -> Callable[[np.ndarray, np.ndarray, np.ndarray, int], np.ndarray]:
    def inject(t: np.ndarray, g: np.ndarray, a: np.ndarray, k: int) -> np.ndarray:
        return ~((t >= t[k]) & (t < t[k] + round(gap_s * S)))

    return inject


def _gps_step(st: Streams, at_ns: int) -> None:
    st.gps_p[st.gps_t >= at_ns, 0] += 50.0  # 50 m east from the fault to the end


def _gps_lost(st: Streams, at_ns: int) -> None:
    st.gps_t[st.gps_t >= at_ns] = -1  # marked for removal (``faulty_copy`` drops them)


def _gps_lost_10s(st: Streams, at_ns: int) -> None:
    st.gps_t[(st.gps_t >= at_ns) & (st.gps_t < at_ns + 10 * S)] = -1


def _gps_frozen(st: Streams, at_ns: int) -> None:
    sel = (st.gps_t >= at_ns) & (st.gps_t < at_ns + 10 * S)
    if sel.any():
        first = np.flatnonzero(sel)[0]
        st.gps_p[sel] = st.gps_p[first]
        if len(st.gps_v) == len(st.gps_t):  # a hung receiver repeats its velocity too
            st.gps_v[sel] = st.gps_v[first]


def _gps_multipath(st: Streams, at_ns: int) -> None:
    # Reflected signals: each fix off by its own 10 m (1 sigma per axis), about no trend; one
    # fixed draw (tests/test_navigator_faults.py injects the same into KITTI raw).
    sel = (st.gps_t >= at_ns) & (st.gps_t < at_ns + 10 * S)
    rng = np.random.default_rng(0)
    st.gps_p[sel] += rng.normal(0.0, 10.0, (int(sel.sum()), 3))


def _gps_velocity_off(st: Streams, at_ns: int) -> None:
    # The receiver's velocity 5 m/s off east from the fault to the end (a failed Doppler
    # solution, a velocity in another frame); its positions stay right.
    st.gps_v[st.gps_t >= at_ns, 0] += 5.0


def _gps_ramp(st: Streams, at_ns: int) -> None:
    # A position solution that drifts off at 1 m/s east for 10 s, then recovers (a float
    # solution wandering until it fixes again); the velocity stays right.
    sel = (st.gps_t >= at_ns) & (st.gps_t < at_ns + 10 * S)
    st.gps_p[sel, 0] += 1.0 * (st.gps_t[sel] - at_ns) / S


def _mag_dead(st: Streams, at_ns: int) -> None:
    st.mag_m[st.mag_t >= at_ns] = 0.0


def _mag_disturbed(st: Streams, at_ns: int) -> None:
    # Steel nearby (a car, rebar): for 10 s the field the sensor sees is turned 8 degrees
    # about its z axis, its magnitude kept: each sample passes its gate, all lean one way.
    sel = (st.mag_t >= at_ns) & (st.mag_t < at_ns + 10 * S)
    c, s_ = np.cos(np.radians(8.0)), np.sin(np.radians(8.0))
    Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    st.mag_m[sel] = st.mag_m[sel] @ Rz.T


def _sonar_bad(st: Streams, at_ns: int) -> None:
    sel = np.flatnonzero((st.sonar_t >= at_ns) & (st.sonar_t < at_ns + 5 * S))
    st.sonar_r[sel] = -1.0
    st.sonar_r[sel[::3]] = 40.0  # a false echo far beyond the ground


IMU_FAULTS = (
    Fault("accel 1000 m/s² x1", 0.0, _imu(_spike_accel)),
    Fault("accel 16 g x3", 0.03, _imu(_saturate)),
    Fault("gyro 35 rad/s x1", 0.0, _imu(_spike_gyro)),
    Fault("zeros 1 s", 1.0, _imu(_zeros)),
    Fault("frozen 1 s", 1.0, _imu(_frozen)),
    Fault("gap 5 s", 5.0, _imu(_gap(5.0))),
    Fault("accel step +0.5 m/s²", 0.0, _imu(_accel_step)),
    Fault("gyro step +0.05 rad/s", 0.0, _imu(_gyro_step)),
)
OTHER_FAULTS = (
    Fault("GPS step 50 m", 0.0, _gps_step),
    Fault("GPS lost (reference)", 0.0, _gps_lost),
    Fault("GPS frozen 10 s", 10.0, _gps_frozen),
    Fault("GPS lost 10 s (reference)", 10.0, _gps_lost_10s),
    Fault("GPS multipath 10 s", 10.0, _gps_multipath),
    Fault("GPS velocity +5 m/s", 0.0, _gps_velocity_off),
    Fault("GPS ramp 1 m/s 10 s", 10.0, _gps_ramp),
    Fault("mag dead", 0.0, _mag_dead),
    Fault("mag turned 8° 10 s", 10.0, _mag_disturbed),
    Fault("sonar bad 5 s", 5.0, _sonar_bad),
)
ALL_SPACING_S = 1.5  # s between the IMU classes of "all at once"


def _in_turn(imu_faults: tuple[Fault, ...]) -> tuple[list[float], float]:
    """Start (s after the fault) of each IMU class of "all at once", ``ALL_SPACING_S`` after
    the one before ended, and the span of them all (s, at least 10)."""
    starts, t = [], 0.0
    for f in imu_faults:
        starts.append(t)
        t += max(f.duration_s, 0.0) + ALL_SPACING_S
    return starts, max(t - ALL_SPACING_S, 10.0)


def all_at_once(imu_faults: tuple[Fault, ...]) -> Fault:
    """Every IMU class in turn, ``ALL_SPACING_S`` apart (a class starts when the one before
    ended), with the frozen GPS, the dead magnetometer and the bad sonar from the fault on."""
    starts, span = _in_turn(imu_faults)

    def inject(st: Streams, at_ns: int) -> None:
        for f, t0 in zip(imu_faults, starts, strict=True):
            f.inject(st, at_ns + round(t0 * S))
        for f in (_gps_frozen, _mag_dead, _sonar_bad):
            f(st, at_ns)

    return Fault("all at once", span, inject)


def _drop(st: Streams, at_ns: int) -> None:
    """The one IMU sample at ``at_ns`` left out (a spike the guard drops)."""
    k = int(np.searchsorted(st.t, at_ns))
    st.keep[k] = False


def _mag_lost(st: Streams, at_ns: int) -> None:
    st.mag_t[st.mag_t >= at_ns] = -1  # marked for removal (``faulty_copy`` drops them)


def _sonar_lost_5s(st: Streams, at_ns: int) -> None:
    st.sonar_t[(st.sonar_t >= at_ns) & (st.sonar_t < at_ns + 5 * S)] = -1


def data_lost(imu_faults: tuple[Fault, ...]) -> Fault:
    """The reference of "all at once": the same data with what its faults destroy left out
    instead of corrupted: each IMU class's samples (a spike's one sample, the window of the
    saturation, zeros, frozen output and gap), the 10 s of frozen fixes, the magnetometer from
    the fault on, the 5 s of bad sonar. The bias steps are not a loss of data and are not
    applied: what "all at once" adds to this run is the steps and whatever the detection of
    the rest costs."""
    starts, span = _in_turn(imu_faults)

    def inject(st: Streams, at_ns: int) -> None:
        for f, t0 in zip(imu_faults, starts, strict=True):
            at = at_ns + round(t0 * S)
            if "step" in f.name:
                continue
            if f.duration_s > 0:
                _imu(_gap(f.duration_s))(st, at)
            else:
                _drop(st, at)
        for lose in (_gps_lost_10s, _mag_lost, _sonar_lost_5s):
            lose(st, at_ns)

    return Fault("data lost (reference for all at once)", span, inject)


FAULTS = (Fault("clean", 0.0, lambda st, at_ns: None), *IMU_FAULTS, *OTHER_FAULTS,
          all_at_once(IMU_FAULTS), data_lost(IMU_FAULTS))  # fmt: skip


def selected(gap_s: float, names: str | None) -> tuple[Fault, ...]:
    """``FAULTS`` with the gap ``gap_s`` long (s); only the clean run and those whose name
    starts with one of the comma-separated ``names`` (None: all)."""
    imu = tuple(Fault(f"gap {gap_s:g} s", gap_s, _imu(_gap(gap_s))) if f.name.startswith("gap ")
                else f for f in IMU_FAULTS)  # fmt: skip
    faults = (FAULTS[0], *imu, *OTHER_FAULTS, all_at_once(imu), data_lost(imu))
    if names is None:
        return faults
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    return tuple(f for f in faults
                 if f.name == "clean" or any(f.name.startswith(w) for w in wanted))  # fmt: skip


def faulty_copy(clean: Path, fault: Fault, at_s: float, out: Path, guard: bool) -> Path:
    """Copy the data set at ``clean`` to ``out`` with ``fault`` injected at ``at_s`` (s after
    the first IMU sample); with ``guard``, the samples :class:`ImuGuard` drops are left out of
    the copy (what the wired guard will do, minus the covariance inflation over gaps)."""
    shutil.copytree(clean, out)
    ds = load_dataset(clean)
    assert ds.imu is not None and ds.imu_calib is not None
    empty3, empty = np.zeros((0, 3)), np.zeros(0)
    st = Streams(
        ds.imu.t_ns.copy(), ds.imu.gyro_B.copy(), ds.imu.accel_B.copy(),
        np.ones(ds.imu.t_ns.size, bool),
        ds.gps.t_ns.copy() if ds.gps else np.zeros(0, np.int64),
        ds.gps.p_W_G.copy() if ds.gps else empty3,
        ds.mag.t_ns.copy() if ds.mag else np.zeros(0, np.int64),
        ds.mag.m_S.copy() if ds.mag else empty3,
        ds.sonar.t_ns.copy() if ds.sonar else np.zeros(0, np.int64),
        ds.sonar.range_m.copy() if ds.sonar else empty,
        ds.gps.v_W_G.copy() if ds.gps else empty3,
    )  # fmt: skip
    fault.inject(st, round(at_s * S))  # the simulator's clock starts at 0
    keep = st.keep
    if guard:
        imu_guard = ImuGuard.from_calib(ds.imu_calib)
        keep &= np.array([imu_guard.check(int(ti), gi, ai).accepted
                          for ti, gi, ai in zip(st.t, st.g, st.a, strict=True)])  # fmt: skip
    w = AslWriter(out)
    w.write_imu(ImuStream(st.t[keep], st.g[keep], st.a[keep]), ds.imu_calib)
    if ds.gps is not None and ds.gps_calib is not None:
        ok = st.gps_t >= 0
        w.write_gps(GpsStream(st.gps_t[ok], st.gps_p[ok], st.gps_v[ok]), ds.gps_calib)
    if ds.mag is not None and ds.mag_calib is not None:
        ok = st.mag_t >= 0
        w.write_mag(MagStream(st.mag_t[ok], st.mag_m[ok]), ds.mag_calib)
    if ds.sonar is not None and ds.sonar_calib is not None:
        ok = st.sonar_t >= 0
        w.write_sonar(SonarStream(st.sonar_t[ok], st.sonar_r[ok]), ds.sonar_calib)
    return out


def gps_back_after_s(ds: Dataset, res: RunResult, fault_end_ns: int) -> float | None:
    """Seconds from ``fault_end_ns`` to the first accepted GPS update at or after it (None:
    never), from the run's update log (a fix dropped as implausible has no update)."""
    ok = [r.t_ns for r in res.update_log
          if r.sensor == "gps" and r.stats.accepted and r.t_ns >= fault_end_ns]  # fmt: skip
    return (int(ok[0]) - fault_end_ns) / S if ok else None


BLOCKS = (slice(0, 9), slice(0, 3), slice(3, 6), slice(6, 9))  # all, position, velocity, attitude


@dataclass(frozen=True)
class Outcome:
    """One run's figures: RMSE [m], its ratio to the clean run, NEES after the fault (9 dof,
    then the p/v/θ blocks) and the GPS return [s] (None: never)."""

    rmse_m: float
    ratio: float
    nees_after: tuple[float, float, float, float]
    gps_back_s: float | None
    nees_windows: tuple[float, ...] = ()


def outcome(ds: Dataset, res: RunResult, clean_rmse: float | None, at_s: float,
            fault: Fault, windows: tuple[tuple[float, float], ...] = ()) -> Outcome:  # fmt: skip
    """The figures of run ``res`` of ``fault`` on ``ds`` (``clean_rmse`` None: the clean run);
    ``windows`` (s from the start, ``[a, b)``) each add their mean NEES (9 dof)."""
    rmse = float(res.report["position_rmse_m"])
    end_ns = int((at_s + fault.duration_s) * S)
    assert ds.groundtruth is not None
    inside, p, v, q = interpolate_groundtruth(ds.groundtruth, res.t_ns)
    t_ns = np.asarray(res.t_ns)[inside]
    e_all = navigation_errors(res.x[inside], p, v, q)
    P_all = res.P9[inside]
    after = t_ns >= end_ns
    e, P = e_all[after], P_all[after]
    nees = tuple(float(nees_of(e[:, b], P[:, b, b]).mean()) for b in BLOCKS)
    in_windows = [(t_ns >= a * S) & (t_ns < b * S) for a, b in windows]
    nees_windows = tuple(float(nees_of(e_all[w], P_all[w]).mean()) for w in in_windows)
    return Outcome(rmse, rmse / clean_rmse if clean_rmse else 1.0, nees,  # type: ignore[arg-type]
                   gps_back_after_s(ds, res, end_ns), nees_windows)  # fmt: skip


def row(res: RunResult, out: Outcome, fault: Fault) -> str:
    rep = res.report
    rejected = sum(c["rejected"] for c in rep.get("measurements", {}).values())
    recovery = rep.get("recovery")
    resets = (
        f"{recovery.get('resets', 0)}/{recovery.get('inflations', 0)}/"
        f"{recovery.get('bias_shifts', 0)}" if recovery else "-"
    )
    back_txt = "never" if out.gps_back_s is None else f"{out.gps_back_s:.1f}"
    n9, n_p, n_v, n_a = out.nees_after
    windows = "".join(f" {n:.3g} |" for n in out.nees_windows)
    return (
        f"| {fault.name} | {rep['method']} | {out.rmse_m:.3f} | {out.ratio:.2f} | {rejected} | "
        f"{resets} | {n9:.3g} | {n_p:.2f} / {n_v:.2f} / {n_a:.2f} | {back_txt} |{windows}"
    )


def summary(results: dict[tuple[str, str], list[Outcome]], seeds: list[int],
            windows: tuple[tuple[float, float], ...] = ()) -> None:  # fmt: skip
    """The table over the seeds (one row per fault and method); the GPS step's, the frozen
    GPS's rows also give the RMSE against the same seed's run without those fixes (what no
    estimator can beat: a frozen fix carries nothing, a step that nothing contradicts
    neither), all at once's against the run with all the data its faults destroy left out
    (:func:`data_lost`)."""
    print(f"\nOver seeds {', '.join(map(str, seeds))}:\n")
    print("| fault | method | NEES after: mean (max) | seeds > 12 | x clean: mean (max) | "
          "x data lost: mean (max) | GPS back, latest [s] |" + _window_heads(windows))  # fmt: skip
    print("|---|---|---|---|---|---|---|" + "---|" * len(windows))
    for (fault, method), outs in results.items():
        nees = np.array([o.nees_after[0] for o in outs])
        ratio = np.array([o.ratio for o in outs])
        back = [o.gps_back_s for o in outs]
        back_txt = "never" if None in back else f"{max(b for b in back if b is not None):.1f}"
        reference = {"GPS step": "GPS lost (reference)",
                     "GPS frozen": "GPS lost 10 s (reference)",
                     "GPS multipath": "GPS lost 10 s (reference)",
                     "GPS ramp": "GPS lost 10 s (reference)",
                     "all at once": "data lost (reference for all at once)"}  # fmt: skip
        ref_name = next((r for f, r in reference.items() if fault.startswith(f)), None)
        lost = results.get((ref_name, method)) if ref_name else None
        vs_lost = "-"
        if lost is not None and len(lost) == len(outs):
            r = np.array([o.rmse_m / ref.rmse_m for o, ref in zip(outs, lost, strict=True)])
            vs_lost = f"{r.mean():.2f} ({r.max():.2f})"
        in_windows = np.array([o.nees_windows for o in outs]).reshape(len(outs), -1)
        print(f"| {fault} | {method} | {nees.mean():.2f} ({nees.max():.2f}) | "
              f"{int((nees > 12).sum())}/{nees.size} | {ratio.mean():.2f} ({ratio.max():.2f}) | "
              f"{vs_lost} | {back_txt} |" + "".join(f" {n:.2f} |" for n in in_windows.mean(0)))


def _window_heads(windows: tuple[tuple[float, float], ...]) -> str:
    return "".join(f" NEES {a:g}-{b:g} s |" for a, b in windows)


def parse_window(text: str) -> tuple[float, float]:
    """``"10:12.5"`` -> (10.0, 12.5) (s from the start of the run)."""
    a, sep, b = text.partition(":")
    if not sep or float(b) <= float(a):
        raise argparse.ArgumentTypeError(f"a window is START:END in seconds, END > START: {text!r}")
    return float(a), float(b)


def parse_seeds(text: str) -> list[int]:
    """``"0-7"``, ``"0,1,5"`` or ``"3"`` -> seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds += list(range(int(lo), int(hi or lo) + 1))
    return seeds


def run_seed(seed: int, args: argparse.Namespace, options: RunOptions,
             results: dict[tuple[str, str], list[Outcome]]) -> None:  # fmt: skip
    """Simulate the flight of ``seed``, run every fault and method, print a row each."""
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    cfg = SimConfig(duration_s=30.0, seed=seed)
    cfg.camera.render_images = False
    cfg.gps.outages = []
    with tempfile.TemporaryDirectory() as tmp:
        clean = simulate(cfg, Path(tmp) / "clean")
        clean_rmse: dict[str, float] = {}
        for i, fault in enumerate(selected(args.gap_s, args.faults)):
            root = faulty_copy(clean, fault, args.at, Path(tmp) / f"fault{i}", args.guard)
            ds = load_dataset(root)
            for method in methods:
                res = run_method(ds, method, options)
                out = outcome(ds, res, clean_rmse.get(method), args.at, fault,
                              tuple(args.nees_window))  # fmt: skip
                if fault.name == "clean":
                    clean_rmse[method] = out.rmse_m
                results.setdefault((fault.name, method), []).append(out)
                print(row(res, out, fault), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", "--seed", default="0", help="seeds: 0, 0,1 or 0-7")
    ap.add_argument("--at", type=float, default=10.0, help="fault time (s from the start)")
    ap.add_argument("--methods", default="ins,3d")
    ap.add_argument("--gap-s", type=float, default=5.0, help="length of the IMU gap (s)")
    ap.add_argument("--faults", default=None,
                    help="only these classes (name prefixes, comma-separated; clean always runs)")
    ap.add_argument("--guard", action="store_true",
                    help="drop the samples ImuGuard rejects before the run (a preview of item 1)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="run setting override (repeatable)")
    ap.add_argument("--nees-window", action="append", default=[], type=parse_window,
                    metavar="START:END", help="also the mean NEES over this window (s from the "
                    "start of the run; repeatable)")
    args = ap.parse_args()
    seeds = parse_seeds(args.seeds)
    options = with_settings(RunOptions(init=InitOptions(mode="groundtruth")),
                            dict(parse_setting(item) for item in args.set))  # fmt: skip
    results: dict[tuple[str, str], list[Outcome]] = {}
    windows = tuple(args.nees_window)
    print("| fault | method | pos RMSE [m] | x clean | rejected | resets/inflations/bias | "
          "NEES after | p / v / θ | GPS back after [s] |" + _window_heads(windows))  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|" + "---|" * len(windows))
    for seed in seeds:
        if len(seeds) > 1:
            print(f"| seed {seed} | | | | | | | | |")
        run_seed(seed, args, options, results)
    if len(seeds) > 1:
        summary(results, seeds, windows)


if __name__ == "__main__":
    main()
