"""Time ``svains convert`` on the EuRoC micro set written as ROS bags (issue 14: ≤ 5 s).

The micro set (95 stereo pairs, the whole 145 s IMU and ground truth) is written once as a ROS1
bag and a ROS2 mcap bag with Kalibr files from its sensor.yaml, then each is converted to the ASL
layout, best of ``--repeat``. Also timed: the in-memory read (what ``svains run BAG`` does).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from svains.datasets import load_dataset
from svains.datasets.kalibr import write_camchain, write_kalibr_imu
from svains.datasets.rosbag_convert import convert_bag
from svains.datasets.rosbag_writer import write_bag

MICRO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print("load average:", Path("/proc/loadavg").read_text().split()[:3])
    ds = load_dataset(MICRO)
    assert ds.cam0 is not None and ds.cam1 is not None and ds.imu_calib is not None
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        chain = write_camchain(d / "camchain-imucam.yaml", [ds.cam0, ds.cam1])
        imu = write_kalibr_imu(d / "imu.yaml", ds.imu_calib)
        for fmt, name in (("ros1", "micro.bag"), ("mcap", "micro_mcap")):
            t0 = time.perf_counter()
            bag = write_bag(ds, d / name, fmt)  # type: ignore[arg-type]
            size_mb = sum(f.stat().st_size for f in [bag, *bag.rglob("*")] if f.is_file()) / 1e6
            print(f"{fmt}: wrote {size_mb:.0f} MB in {time.perf_counter() - t0:.2f} s")
            best, best_cpu, best_read = float("inf"), float("inf"), float("inf")
            for k in range(args.repeat):
                out = d / f"out_{fmt}_{k}"
                rep = convert_bag(bag, out, calib=chain, imu_calib=imu)
                best, best_cpu = min(best, rep.wall_s), min(best_cpu, rep.cpu_s)
                shutil.rmtree(out)
                t0 = time.perf_counter()
                load_dataset(bag, calib=chain, imu_calib=imu)
                best_read = min(best_read, time.perf_counter() - t0)
            print(
                f"{fmt}: convert {rep.counts} best of {args.repeat}: {best:.2f} s wall, "
                f"{best_cpu:.2f} s CPU (target ≤ 5 s)"
            )
            print(f"{fmt}: in-memory read with calibration, best: {best_read:.2f} s")
    print("load average:", Path("/proc/loadavg").read_text().split()[:3])


if __name__ == "__main__":
    main()
