"""The fault classes of ``bench/faults.py`` injected into a real data set, run as a user runs it.

Plain script (not a timed test). For each class (IMU spikes, saturation, zeros, frozen output,
a gap, bias steps; GPS step, GPS lost, frozen GPS, GPS lost 10 s, GPS multipath, GPS velocity
off, GPS ramp when the data set has GPS; all at once; the magnetometer and sonar classes are
left out: the shared real data sets have neither; with ``--images`` among the run's arguments,
camera classes too: ``CAMERA_FAULTS``) it writes a copy of the data set into a temporary folder
(``imu0`` and ``gps0`` rewritten, every other entry a symbolic link to the original: nothing of
it is copied or changed), injects the fault ``--at`` seconds after the first IMU sample and
runs ``svains run COPY --method M ARGS...`` in a subprocess. It prints the exit code, the
position RMSE and its ratio to the clean run's, the ATE, the NEES, the final error and the
run's last line when it failed. "x lost" holds the GPS step to the run with the fixes removed
from the fault on, and the frozen GPS, the multipath and the ramp to the run with those 10 s
removed (nothing else can do better when nothing contradicts them).

    python bench/real_faults.py ../shared/data/kitti_raw_0926_41s --method ins -- \
        --init gps --no-mag
    python bench/real_faults.py ../shared/data/kitti_raw_0926_41s --method 3d -- \
        --images --init gps --no-mag
    python bench/real_faults.py ../shared/data/euroc_v101_micro --method 3d --at 20 -- \
        --synthetic-features 5 --no-gps --no-mag
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from faults import FAULTS, Fault, S, Streams  # bench/faults.py: the fault classes

from svains.datasets import load_dataset
from svains.datasets.asl_writer import AslWriter
from svains.datasets.types import Dataset, GpsStream, ImuStream

# What each GPS fault is held to (the same fixes removed): nothing does better without them.
REFERENCE = {"GPS step 50 m": "GPS lost (reference)",
             "GPS frozen 10 s": "GPS lost 10 s (reference)",
             "GPS multipath 10 s": "GPS lost 10 s (reference)",
             "GPS ramp 1 m/s 10 s": "GPS lost 10 s (reference)"}


def applies(fault: Fault, ds: Dataset) -> bool:
    """Whether ``fault`` has a stream to act on in ``ds`` (no magnetometer or sonar classes;
    GPS classes only with GPS)."""
    if fault.name.startswith(("mag", "sonar")):
        return False
    return ds.gps is not None or not fault.name.startswith("GPS")


def faulty_copy(data: Path, ds: Dataset, fault: Fault, at_s: float, out: Path) -> Path:
    """``out``: ``data`` with ``fault`` injected ``at_s`` after its first IMU sample; ``imu0``
    and ``gps0`` rewritten, the rest linked."""
    assert ds.imu is not None and ds.imu_calib is not None
    (out / "mav0").mkdir(parents=True)
    for entry in (data / "mav0").iterdir():
        if entry.name in ("imu0", "gps0"):
            shutil.copytree(entry, out / "mav0" / entry.name)  # rewritten below, never linked
        else:
            os.symlink(entry, out / "mav0" / entry.name)
    gps = ds.gps
    st = Streams(ds.imu.t_ns.copy(), ds.imu.gyro_B.copy(), ds.imu.accel_B.copy(),
                 np.ones(ds.imu.t_ns.size, bool),
                 gps.t_ns.copy() if gps else np.zeros(0, np.int64),
                 gps.p_W_G.copy() if gps else np.zeros((0, 3)),
                 np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64),
                 np.zeros(0), gps.v_W_G.copy() if gps else np.zeros((0, 3)))  # fmt: skip
    fault.inject(st, int(ds.imu.t_ns[0]) + round(at_s * S))
    w = AslWriter(out)
    w.write_imu(ImuStream(st.t[st.keep], st.g[st.keep], st.a[st.keep]), ds.imu_calib)
    if gps is not None and ds.gps_calib is not None:
        ok = st.gps_t >= 0  # the lost classes mark the fixes they remove
        w.write_gps(GpsStream(st.gps_t[ok], st.gps_p[ok], st.gps_v[ok]), ds.gps_calib)
    return out


# Camera classes (runs on images, ``--images`` among the run's arguments): both cameras for
# CAMERA_S from the fault time show black, repeat the pair before the fault byte for byte
# (a frozen driver), show that scene with new noise (stuck: blocked, or a replayed frame
# re-encoded), or show noise alone; the right camera alone black (a loose cable); the left
# image's left half black (a finger or a prop over the lens); both a quarter as bright (an
# exposure drop); every other pair half as bright (flicker under mains light); both blurred
# (Gaussian, sigma 4 px: a fast pan in low light).
CAMERA_FAULTS = ("camera black", "camera frozen", "camera stuck", "camera noise",
                 "camera right black", "camera half covered", "camera dark", "camera flicker",
                 "camera blur")  # fmt: skip
CAMERA_S = 3.0


def camera_copy(data: Path, kind: str, at_s: float, out: Path) -> Path:
    """``out``: ``data`` with the camera fault ``kind`` for ``CAMERA_S`` from ``at_s`` after
    the first image; the untouched images linked."""
    (out / "mav0").mkdir(parents=True)
    for entry in (data / "mav0").iterdir():
        if entry.name not in ("cam0", "cam1"):
            os.symlink(entry, out / "mav0" / entry.name)
            continue
        cam = out / "mav0" / entry.name
        (cam / "data").mkdir(parents=True)
        for name in ("data.csv", "sensor.yaml"):
            shutil.copy(entry / name, cam / name)
        files = sorted((entry / "data").iterdir())
        t = np.array([int(f.stem) for f in files])
        t0 = t[0] + round(at_s * S)
        first = None
        rng = np.random.default_rng(0)
        touched = {"camera right black": "cam1", "camera half covered": "cam0"}.get(kind)
        for k, (f, ti) in enumerate(zip(files, t, strict=True)):
            dst = cam / "data" / f.name
            if not t0 <= ti < t0 + round(CAMERA_S * S) or touched not in (None, entry.name):
                os.symlink(f, dst)
                continue
            if kind in ("camera right black", "camera half covered", "camera dark",
                        "camera flicker", "camera blur"):  # fmt: skip
                img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
                if kind == "camera right black":
                    img = np.zeros_like(img)
                elif kind == "camera half covered":
                    img[:, : img.shape[1] // 2] = 0
                elif kind == "camera dark" or (kind == "camera flicker" and k % 2):
                    img = (img.astype(np.float64) * (0.25 if kind == "camera dark" else 0.5)
                           ).astype(img.dtype)  # fmt: skip
                elif kind == "camera blur":
                    img = cv2.GaussianBlur(img, (0, 0), 4.0)
                cv2.imwrite(str(dst), img)
                continue
            first = first or f
            img = cv2.imread(str(first if kind != "camera black" else f), cv2.IMREAD_UNCHANGED)
            if kind == "camera frozen":
                os.symlink(first, dst)
                continue
            if kind == "camera black":
                img = np.zeros_like(img)
            elif kind == "camera stuck":
                img = np.clip(img + rng.normal(0.0, 2.0, img.shape), 0, 255).astype(np.uint8)
            else:
                img = rng.integers(0, 256, img.shape, dtype=np.uint8)
            cv2.imwrite(str(dst), img)
    return out


def run(root: Path, method: str, args: list[str], out: Path) -> tuple[int, dict[str, Any], str]:
    """``svains run`` on ``root``: exit code, report (empty without one), last stderr line."""
    svains = Path(sys.executable).with_name("svains")
    cmd = [str(svains), "run", str(root), "--method", method, "--out", str(out), *args]
    p = subprocess.run(cmd, capture_output=True, text=True)
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    report = out / "report.json"
    rep = json.loads(report.read_text(encoding="utf-8")) if report.exists() else {}
    return p.returncode, rep, lines[-1] if lines else ""


def warned_checks(rep: dict[str, Any], prefix: str = "") -> list[str]:
    """The report's input checks that warned: every ``warned*`` key that is true, by path
    (``vision.scale_check.warned_gps``)."""
    out: list[str] = []
    for key, value in rep.items():
        if isinstance(value, dict):
            out += warned_checks(value, f"{prefix}{key}.")
        elif key.startswith("warned") and value is True:
            out.append(f"{prefix}{key}")
    return out


def figure(rep: dict[str, Any], key: str) -> float:
    v = rep.get(key)
    return float(v) if isinstance(v, int | float) else math.nan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--method", default="ins")
    ap.add_argument("--at", type=float, default=10.0,
                    help="fault time (s after the first IMU sample)")
    ap.add_argument("--faults", default=None,
                    help="comma-separated name prefixes: only those classes (and the clean "
                         "run and the references they are held to)")
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    args = ap.parse_args(argv[:cut])
    args.run_args = argv[cut + 1 :]  # after --: the arguments of svains run
    data = args.data.resolve()
    ds = load_dataset(data)
    print(f"## {data.name}, `{args.method}` {' '.join(args.run_args)}, faults at {args.at:g} s\n")
    print("| fault | exit | pos RMSE [m] | x clean | x lost | ATE [m] | NEES | final [%] | "
          "checks warned | last line |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rmse: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        # The references first: the rows of the faults held to them can then give "x lost".
        gps_used = "--no-gps" not in args.run_args
        faults = sorted((f for f in FAULTS if applies(f, ds)
                         and (gps_used or not f.name.startswith("GPS"))),
                        key=lambda f: (f.name != "clean", f.name not in REFERENCE.values()))
        names = [f.name for f in faults]
        if "--images" in args.run_args:
            names += list(CAMERA_FAULTS)
        if args.faults is not None:
            wanted = tuple(p.strip() for p in args.faults.split(",") if p.strip())
            chosen = [n for n in names if n.startswith(wanted)]
            names = [n for n in names if n == "clean" or n in chosen
                     or n in {REFERENCE.get(c) for c in chosen}]  # fmt: skip
        for i, name in enumerate(names):
            out = Path(tmp) / f"data{i}"
            root = (camera_copy(data, name, args.at, out) if name in CAMERA_FAULTS else
                    faulty_copy(data, ds, next(f for f in faults if f.name == name), args.at,
                                out))  # fmt: skip
            code, rep, last = run(root, args.method, args.run_args, Path(tmp) / f"out{i}")
            shutil.rmtree(root)
            rmse[name] = r = figure(rep, "position_rmse_m")
            clean = rmse.get("clean", math.nan)
            ref = rmse.get(REFERENCE.get(name, ""), math.nan)
            lost = f"{r / ref:.2f}" if math.isfinite(ref) else "-"
            print(f"| {name} | {code} | {r:.3f} | {r / clean:.2f} | {lost} | "
                  f"{figure(rep, 'ate_rmse_m'):.3f} | {figure(rep, 'nees_mean'):.2f} | "
                  f"{figure(rep, 'final_error_pct'):.2f} | {', '.join(warned_checks(rep)) or '-'} "
                  f"| {last[:120] if code else ''} |",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
