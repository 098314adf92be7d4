"""A magnetometer read through the wrong mount: does a GPS-aided run survive it? Plain script
(not a timed test).

Magnetometers are often mounted or wired with axes that differ from the IMU's, and a
``T_BS`` that misses it gives a heading off by a constant (a turn about the vertical) or a
field that turns the wrong way (a mirrored axis). Per seed, a simulated 30 s village flight
(``SimConfig(duration_s=30, seed=seed)``, feature-level, GPS at 1 Hz throughout) has its
``mag0`` samples replaced by ``M m_S`` for each mount ``M`` below while ``mag0/sensor.yaml``
keeps the identity ``T_BS``:

- ``yaw 90°``: the sensor turned a quarter turn about its z axis;
- ``AK8963``: the MPU-9250's magnetometer axes against its accelerometer's (x and y swapped,
  z reversed: a half turn about the x = y diagonal);
- ``x reversed``: one axis mirrored (LSM9DS1-style wiring).

``ins`` and ``3d`` run through ``svains.evaluation.run.run_method`` with an in-flight start
(``--init gps``: the start's heading from the magnetometer), with the heading check
(``faults.heading_check``, default) and without it. Prints per mount and method the mean over
the seeds of the position and attitude RMSE [m, deg] against the ground truth and the turns
the check made, and per mount the load-time test of the field's turns against the gyro's
(``datasets.validate.mag_frame_turn``: the cosine, +1 for a right mount; below -0.7 a file is
refused, and online the magnetometer is left out, ``mag_turn_check``).

    python bench/mag_mount.py [--seeds 0-3] [--methods ins,3d] [--init gps] [--no-sonar]
                              [--camera-turns 30,90]

``--camera-turns`` adds rows with the magnetometer right and the stereo rig turned on its
mount about the body's vertical (``evaluation.extrinsics.turn_cameras``, the calibration
unchanged): in straight flight that looks the same to the heading check as a wrong heading.
``--no-sonar`` drops the sonar altimeter (most platforms have none; it is the second sensor
that can tell the consistency monitor that the filter, not the GPS, is wrong).
"""

from __future__ import annotations

import argparse
import logging
import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from faults import parse_seeds  # bench/faults.py: "0-7", "0,1,5" or "3"

from svains.datasets import load_dataset
from svains.datasets.types import MagStream
from svains.datasets.validate import mag_frame_turn
from svains.evaluation.extrinsics import turn_cameras
from svains.evaluation.run import run_method
from svains.navigation.options import FaultOptions, InitOptions, RunOptions
from svains.sim import SimConfig, simulate

MOUNTS = {
    "as calibrated": np.eye(3),
    "yaw 90°": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "AK8963": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
    "x reversed": np.diag([-1.0, 1.0, 1.0]),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=parse_seeds, default=[0, 1, 2, 3])
    ap.add_argument("--methods", default="ins,3d")
    ap.add_argument("--init", default="gps", choices=("gps", "groundtruth"))
    ap.add_argument("--no-sonar", action="store_true", help="drop the sonar altimeter")
    ap.add_argument("--camera-turns", default="",
                    help="also rows with the magnetometer right and the stereo rig turned by "
                         "these angles [deg, comma-separated] about the body's vertical on "
                         "its mount (the calibration unchanged)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    camera_turns = [float(a) for a in args.camera_turns.split(",") if a.strip()]
    on = RunOptions(init=InitOptions(mode=args.init))
    off = replace(on, faults=FaultOptions(heading_check=False))
    rows: dict[tuple[str, str, str], list[tuple[float, float, int]]] = {}
    cosines: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            cfg = SimConfig(duration_s=30.0, seed=seed)
            cfg.camera.render_images = False
            cfg.gps.outages = []
            ds = load_dataset(simulate(cfg, Path(tmp) / f"seed{seed}"))
            if args.no_sonar:
                ds = replace(ds, sonar=None)
            assert ds.mag is not None and ds.cam0 is not None
            variants = [(mount, replace(ds, mag=MagStream(ds.mag.t_ns, ds.mag.m_S @ M.T)))
                        for mount, M in MOUNTS.items()]
            up_C0 = np.asarray(ds.cam0.T_B_C, float)[:3, :3].T @ [0.0, 0.0, 1.0]
            variants += [(f"camera turned {deg:g}°", turn_cameras(ds, math.radians(deg) * up_C0))
                         for deg in camera_turns]
            for mount, d in variants:
                turn = mag_frame_turn(d)
                cosines.setdefault(mount, []).append(math.nan if turn is None else turn[0])
                for method in methods:
                    for check, options in (("on", on), ("off", off)):
                        rep = run_method(d, method, options).report
                        turns = len((rep.get("heading_check") or {}).get("turns", []))
                        rows.setdefault((mount, method, check), []).append(
                            (rep["position_rmse_m"], rep["attitude_rmse_deg"], turns))
    print(f"Seeds {', '.join(map(str, args.seeds))}, init {args.init}"
          f"{', no sonar' if args.no_sonar else ''}; mean position RMSE [m] / "
          "attitude RMSE [deg] (turns made)\n")
    print("| mount | method | heading check off | heading check on (default) |")
    print("|---|---|---|---|")
    for mount in list(MOUNTS) + [f"camera turned {deg:g}°" for deg in camera_turns]:
        for method in methods:
            cells = []
            for check in ("off", "on"):
                r = np.array(rows[(mount, method, check)], float)
                cells.append(f"{r[:, 0].mean():.3f} / {r[:, 1].mean():.1f}"
                             + (f" ({int(r[:, 2].sum())})" if check == "on" else ""))
            print(f"| {mount} | {method} | {cells[0]} | {cells[1]} |")
    print("\nfield turns against the gyro's, cosine per seed (+1: right; below -0.7: refused):")
    for mount, cs in cosines.items():
        print(f"  {mount}: {', '.join(f'{c:+.2f}' for c in cs)}")
    worst = max((np.array(v)[:, 0].max(), k) for k, v in rows.items())
    print(f"\nlargest position RMSE: {worst[0]:.2f} m ({', '.join(worst[1])})"
          if math.isfinite(worst[0]) else "")


if __name__ == "__main__":
    main()
