"""Write a ``Dataset`` as a ROS1 ``.bag`` or a ROS2 bag (sqlite3 ``.db3`` or ``.mcap``).

The inverse of ``datasets/rosbag.py`` for IMU, stereo images (``mono8``) and ground-truth poses
(``geometry_msgs/PoseStamped``, frame ``world``): what Kalibr's ``bagcreater`` does for EuRoC
folders, without ROS. Topics default to EuRoC's (``/imu0``, ``/cam0/image_raw``, ...).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np

from svains.datasets.types import Dataset
from svains.errors import ConfigError

BagFormat = Literal["ros1", "db3", "mcap"]
MSGTYPES = {
    "imu": "sensor_msgs/msg/Imu", "left": "sensor_msgs/msg/Image",
    "right": "sensor_msgs/msg/Image", "gt": "geometry_msgs/msg/PoseStamped",
}  # fmt: skip
DEFAULT_TOPICS = {
    "imu": "/imu0", "left": "/cam0/image_raw", "right": "/cam1/image_raw", "gt": "/groundtruth",
}  # fmt: skip


def _stamp(ts: Any, t_ns: int) -> Any:
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def _header(ts: Any, t_ns: int, frame: str, ros1: bool) -> Any:
    Header = ts.types["std_msgs/msg/Header"]
    if ros1:
        return Header(seq=0, stamp=_stamp(ts, t_ns), frame_id=frame)
    return Header(stamp=_stamp(ts, t_ns), frame_id=frame)


def _imu_msgs(ds: Dataset, ts: Any, ros1: bool) -> Iterator[tuple[int, Any]]:
    assert ds.imu is not None
    T = ts.types
    Imu, V3, Q = (
        T["sensor_msgs/msg/Imu"],
        T["geometry_msgs/msg/Vector3"],
        T["geometry_msgs/msg/Quaternion"],
    )
    cov = np.zeros(9)
    no_orientation = np.r_[-1.0, np.zeros(8)]  # REP 145: orientation not provided
    for t, w, a in zip(ds.imu.t_ns.tolist(), ds.imu.gyro_B.tolist(), ds.imu.accel_B.tolist(),
                       strict=True):  # fmt: skip
        yield t, Imu(_header(ts, t, "imu0", ros1), Q(x=0.0, y=0.0, z=0.0, w=1.0), no_orientation,
                     V3(x=w[0], y=w[1], z=w[2]), cov, V3(x=a[0], y=a[1], z=a[2]), cov)  # fmt: skip


def _image_msgs(ds: Dataset, role: str, ts: Any, ros1: bool) -> Iterator[tuple[int, Any]]:
    stream = getattr(ds, role)
    Image = ts.types["sensor_msgs/msg/Image"]
    frame = "cam0" if role == "left" else "cam1"
    for i, t in enumerate(stream.t_ns.tolist()):
        img = stream.load(i)
        h, w = img.shape
        yield t, Image(_header(ts, t, frame, ros1), h, w, "mono8", 0, w,
                       np.ascontiguousarray(img).reshape(-1))  # fmt: skip


def _gt_msgs(ds: Dataset, ts: Any, ros1: bool) -> Iterator[tuple[int, Any]]:
    gt = ds.groundtruth
    assert gt is not None
    T = ts.types
    PoseStamped, Pose = T["geometry_msgs/msg/PoseStamped"], T["geometry_msgs/msg/Pose"]
    Point, Q = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    for t, p, q in zip(gt.t_ns.tolist(), gt.p_W_B.tolist(), gt.q_W_B_wxyz.tolist(), strict=True):
        pose = Pose(Point(x=p[0], y=p[1], z=p[2]), Q(x=q[1], y=q[2], z=q[3], w=q[0]))
        yield t, PoseStamped(_header(ts, t, "world", ros1), pose)


def _streams(ds: Dataset, ts: Any, ros1: bool) -> dict[str, Iterator[tuple[int, Any]]]:
    out: dict[str, Iterator[tuple[int, Any]]] = {}
    if ds.imu is not None:
        out["imu"] = _imu_msgs(ds, ts, ros1)
    for role in ("left", "right"):
        if getattr(ds, role) is not None:
            out[role] = _image_msgs(ds, role, ts, ros1)
    if ds.groundtruth is not None:
        out["gt"] = _gt_msgs(ds, ts, ros1)
    return out


def _tagged(role: str, it: Iterator[tuple[int, Any]]) -> Iterator[tuple[int, str, Any]]:
    for t, msg in it:
        yield t, role, msg


def write_bag(
    ds: Dataset,
    path: Path | str,
    fmt: BagFormat = "ros1",
    topics: dict[str, str] | None = None,
    t_end_ns: int | None = None,
) -> Path:
    """Write ``ds``'s IMU, images and ground truth to a bag; messages up to ``t_end_ns``.

    ``ros1`` writes the file ``path``; ``db3``/``mcap`` write the ROS2 bag folder ``path``.
    """
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if path.exists():
        raise ConfigError(f"{path} exists; choose a new bag path")
    names = {**DEFAULT_TOPICS, **(topics or {})}
    ros1 = fmt == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    streams = _streams(ds, ts, ros1)
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        writer: Any = Writer1(path)
    else:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    msgtypes = MSGTYPES
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    with writer:
        conns = {r: writer.add_connection(names[r], msgtypes[r], typestore=ts) for r in streams}
        # Record time = stamp, merged across streams so the bag is in time order.
        merged = heapq.merge(*(_tagged(r, it) for r, it in streams.items()), key=lambda x: x[0])
        for t, role, msg in merged:
            if t_end_ns is not None and t > t_end_ns:
                break  # merged in time order: every later message is past the end too
            writer.write(conns[role], t, serialize(msg, msgtypes[role]))
    return path
