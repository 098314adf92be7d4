"""Online use of ``svains.Navigator``: feed EuRoC micro one measurement at a time.

The IMU samples and the stereo images are read straight from the ASL folder (no data-set
object), merged in time order and fed as a robot driver would: ``feed_imu`` per IMU sample,
``feed_stereo`` per image pair (the front end runs inside). The pose is printed at the camera
rate (20 Hz) as the estimator produces it.

Usage: ``python examples/online.py [PATH/TO/euroc_v101_micro] [SECONDS]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from svains import Navigator, NavState, RunConfig
from svains.datasets.asl_reader import read_camera, read_imu
from svains.navigation.options import VisionOptions
from svains.navigation.vision import tune_for_frames
from svains.sensors.types import Rig
from svains.threads import limit_threads

DEFAULT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_v101_micro"


def main(root: Path, seconds: float) -> int:
    mav0 = root / "mav0"
    imu, imu_calib = read_imu(mav0 / "imu0")
    left, cam0, _ = read_camera(mav0 / "cam0")
    right, cam1, _ = read_camera(mav0 / "cam1")
    # Pairs present in both cameras (real data has holes).
    common, il, ir = np.intersect1d(left.t_ns, right.t_ns, return_indices=True)
    t_end = int(imu.t_ns[0]) + int(seconds * 1e9)
    config = RunConfig(method="3d", output_period_s=0.05, vision=VisionOptions(source="images"))
    # The rotation="imu" treatment of the gyro noise between 20 Hz frames.
    config = tune_for_frames(config, imu_calib, 0.05)
    t_imu = (imu.t_ns - imu.t_ns[0]) * 1e-9
    rig = Rig(imu_period_s=float(np.median(np.diff(t_imu))), imu=imu_calib, cam0=cam0, cam1=cam1)
    printed = []

    def show(s: NavState) -> None:
        printed.append(s.t_ns)
        p, q = s.p_W_B, s.q_W_B_wxyz
        print(f"{s.t_ns * 1e-9:.3f} s  p_W_B [m] {p[0]:+.3f} {p[1]:+.3f} {p[2]:+.3f}  "
              f"q_W_B [wxyz] {q[0]:+.4f} {q[1]:+.4f} {q[2]:+.4f} {q[3]:+.4f}  "
              f"sigma_p [m] {np.sqrt(np.trace(s.P[:3, :3])):.3f}")

    nav = Navigator(config, rig, on_output=show)
    k = 0  # next image pair
    with limit_threads():  # small matrices: one BLAS thread is fastest (docs/python-api.md)
        for t, gyro, accel in zip(imu.t_ns, imu.gyro_B, imu.accel_B, strict=True):
            if t > t_end:
                break
            while k < common.size and common[k] <= t:  # images stamped up to this IMU sample
                img_l = cv2.imread(str(left.paths[il[k]]), cv2.IMREAD_GRAYSCALE)
                img_r = cv2.imread(str(right.paths[ir[k]]), cv2.IMREAD_GRAYSCALE)
                nav.feed_stereo(int(common[k]), img_l, img_r)
                k += 1
            nav.feed_imu(int(t), gyro, accel)
        result = nav.close()
    vision = result.report.get("vision", {})
    print(f"{len(printed)} poses; {vision.get('frames_fused', 0)} stereo frames fused; "
          f"front end {vision.get('frontend_status', {})}")
    return 0


if __name__ == "__main__":
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT
    sys.exit(main(path, float(sys.argv[2]) if len(sys.argv) > 2 else 4.5))
