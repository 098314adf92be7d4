"""``svains convert``: a ROS bag to the ASL layout (``docs/formats.md``), calibration from Kalibr.

Images become PNG files in ``cam0/data``/``cam1/data``; the IMU, GPS (local ENU about the first
fix, the origin in ``gps0/enu_origin.yaml``) and ground truth become ``data.csv`` tables. Each
``sensor.yaml`` is written from the Kalibr files, which a folder needs for cameras and the IMU
(bags seldom carry calibration).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets._textio import write_sensor_yaml
from svains.datasets.asl_writer import AslWriter
from svains.datasets.kalibr import apply_kalibr, kalibr_topics
from svains.datasets.rosbag import read_bag
from svains.datasets.types import Dataset, ImageStream
from svains.errors import ConfigError


@dataclass
class ConversionReport:
    """What ``convert_bag`` wrote: samples per stream, chosen topics, wall and CPU time (s)."""

    out: Path
    counts: dict[str, int] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)
    wall_s: float = 0.0
    cpu_s: float = 0.0


def _check_calibrated(ds: Dataset, calib: Path | None, imu_calib: Path | None) -> None:
    if ds.left is not None and ds.cam0 is None:
        raise ConfigError(
            "the bag has images: pass their Kalibr calibration, --calib camchain-imucam.yaml"
        )
    if ds.imu is not None and ds.imu_calib is None:
        raise ConfigError("the bag has an IMU: pass its Kalibr noise file, --imu-calib imu.yaml")
    if ds.right is not None and ds.cam1 is None:
        raise ConfigError(f"{calib}: the camchain needs cam1 for the right images")


def _images(stream: ImageStream) -> Iterator[NDArray[np.uint8]]:
    return (stream.load(i) for i in range(len(stream)))


def convert_bag(
    bag: Path | str,
    out: Path | str,
    topics: dict[str, str | None] | None = None,
    calib: Path | str | None = None,
    imu_calib: Path | str | None = None,
) -> ConversionReport:
    """Write ``bag`` as an ASL data set under ``out`` (``out/mav0/...``).

    ``topics`` chooses roles (imu, left, right, gps, gt; the rest auto-detected). ``calib`` is a
    Kalibr camchain(-imucam), ``imu_calib`` a Kalibr ``imu.yaml``; their ``rostopic`` entries
    choose topics the caller left open, when the bag has them. ``out`` must not hold a data
    set already.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    out = Path(out)
    if (out / "mav0").exists():
        raise ConfigError(f"{out}/mav0 exists; choose an empty output folder")
    ds = read_bag(bag, topics, hints=kalibr_topics(calib, imu_calib))
    ds = apply_kalibr(ds, calib, imu_calib)
    _check_calibrated(ds, Path(calib) if calib else None, Path(imu_calib) if imu_calib else None)
    w = AslWriter(out)
    w.write_body(ds.gravity_W, comment=f"converted from {Path(bag).name}")
    topics_used: dict[str, str] = ds.extras.get("bag_topics", {})  # type: ignore[assignment]
    rep = ConversionReport(out=out, topics=dict(topics_used))
    if ds.imu is not None and ds.imu_calib is not None:
        w.write_imu(ds.imu, ds.imu_calib)
        rep.counts["imu0"] = int(ds.imu.t_ns.size)
    for stream, cal in ((ds.left, ds.cam0), (ds.right, ds.cam1)):
        if stream is not None and cal is not None:
            if cal.distortion_model == "radtan":  # sensor.yaml keeps EuRoC's spelling
                cal = dataclasses.replace(cal, distortion_model="radial-tangential")
            w.write_camera(cal, stream.t_ns, _images(stream))
            rep.counts[cal.name] = len(stream)
    if ds.gps is not None and ds.gps_calib is not None:
        d = w.write_gps(ds.gps, ds.gps_calib)
        lat, lon, alt = ds.extras["gps_enu_origin_lat_lon_alt"]  # type: ignore[misc]
        write_sensor_yaml(
            d / "enu_origin.yaml",
            [("latitude_deg", lat), ("longitude_deg", lon), ("altitude_m", alt)],
            comment="WGS-84 origin of the local East-North-Up world frame (first fix)",
        )
        rep.counts["gps0"] = int(ds.gps.t_ns.size)
    if ds.groundtruth is not None:
        w.write_groundtruth(ds.groundtruth)
        rep.counts["state_groundtruth_estimate0"] = int(ds.groundtruth.t_ns.size)
    rep.wall_s = time.perf_counter() - t0
    rep.cpu_s = time.process_time() - c0
    return rep
