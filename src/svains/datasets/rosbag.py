"""ROS1 ``.bag`` and ROS2 (``.db3``, ``.mcap`` or a bag folder) recordings, read without ROS.

Through ``rosbags``. A bag becomes the same in-memory ``Dataset`` the ASL reader makes:

- ``sensor_msgs/Imu`` -> ``imu`` (``angular_velocity`` rad/s, ``linear_acceleration`` m/s²);
- ``sensor_msgs/Image`` or ``CompressedImage`` -> ``left``/``right`` (8-bit grey, decoded on
  demand from the message bytes, which stay in memory: 0.36 MB per raw 752x480 image, so convert
  long bags with ``svains convert`` first);
- ``sensor_msgs/NavSatFix`` -> ``gps`` in a local ENU frame about the first fix
  (``datasets/geodetic.py``), position only (a NavSatFix holds no velocity; velocities
  differenced from the same fixes would count their noise twice);
- ``PoseStamped``, ``PoseWithCovarianceStamped``, ``TransformStamped`` or ``Odometry`` ->
  ``groundtruth`` (pose only: velocity by central differences, biases zero).

Times are the messages' ``header.stamp`` (sensor time), the bag's record time when a stamp is
zero. Calibration is not in a bag: ``apply_kalibr`` (``datasets/kalibr.py``) adds it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from svains.datasets._image_io import decode_compressed, decode_raw
from svains.datasets.geodetic import geodetic_to_enu
from svains.datasets.trajectory import groundtruth_from_poses
from svains.datasets.types import Dataset, GpsCalib, GpsStream, ImageStream, ImuStream
from svains.errors import ConfigError, DatasetError

log = logging.getLogger(__name__)

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
ROLES = ("imu", "left", "right", "gps", "gt")
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "imu": ("sensor_msgs/msg/Imu",),
    "left": ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"),
    "right": ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"),
    "gps": ("sensor_msgs/msg/NavSatFix",),
    "gt": (
        "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
        "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry",
    ),
}  # fmt: skip
# Topic-name words that say which camera is which (auto-detection of the stereo pair).
_LEFT_WORDS = ("cam0", "left", "infra1", "fisheye1")
_RIGHT_WORDS = ("cam1", "right", "infra2", "fisheye2")
# NavSatFix without a covariance (COVARIANCE_TYPE_UNKNOWN): a consumer receiver's horizontal
# accuracy, m. Overwrite gps0/sensor.yaml after conversion if your receiver is better.
DEFAULT_GPS_POSITION_STD_M = 2.5


@dataclass(frozen=True)
class TopicInfo:
    """One topic: message type, count, median rate (Hz) and span (s) of record times."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None
    span_s: float


def is_bag(path: Path) -> bool:
    """A ROS1/ROS2 bag file, or a ROS2 bag folder (``metadata.yaml``)."""
    if path.is_file():
        return path.suffix.lower() in BAG_SUFFIXES
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise DatasetError(f"bag not found: {path}")
    if path.is_dir() and not is_bag(path):
        raise DatasetError(f"{path}: a folder without a ROS2 metadata.yaml, so not a bag "
                           "(an ASL/EuRoC or KITTI data set is read as it is: svains info, run)")
    # ROS1 bags embed their message definitions; ROS2 ones fall back to this store.
    return AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def _open_error(path: Path, exc: Exception) -> DatasetError:
    return DatasetError(f"{path}: cannot read bag: {exc}")


def bag_topics(path: Path | str, rates: bool = True) -> list[TopicInfo]:
    """Every topic of a bag, sorted by name. ``rates`` reads every record time (median rate
    and span); without it only the index is read (``rate_hz`` None, ``span_s`` 0)."""
    path = Path(path)
    times: dict[str, list[int]] = {}
    types: dict[str, str] = {}
    counts: dict[str, int] = {}
    try:
        with _reader(path) as r:
            for c in r.connections:
                types[c.topic] = c.msgtype
                counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
                times.setdefault(c.topic, [])
            if rates:
                for c, t_ns, _ in r.messages():
                    times[c.topic].append(t_ns)
    except DatasetError:
        raise
    except Exception as exc:  # rosbags raises several unrelated types for broken files
        raise _open_error(path, exc) from exc
    out = []
    for name in sorted(times):
        t = np.sort(np.asarray(times[name], np.int64))
        rate = float(1e9 / np.median(np.diff(t))) if t.size > 1 and np.any(np.diff(t)) else None
        span = float((t[-1] - t[0]) * 1e-9) if t.size else 0.0
        out.append(TopicInfo(name, types[name], counts[name], rate, span))
    return out


def _pick_stereo(cands: list[str], given: dict[str, str | None]) -> dict[str, str]:
    out: dict[str, str] = {}
    for role, words in (("left", _LEFT_WORDS), ("right", _RIGHT_WORDS)):
        if given.get(role):
            continue
        hits = [c for c in cands if any(w in c.lower() for w in words)]
        hits = [c for c in hits if c not in given.values()]
        if len(hits) == 1:
            out[role] = hits[0]
        elif len(cands) > 0:
            raise ConfigError(
                f"cannot tell the {role} camera among image topics {', '.join(cands)}: "
                f"{_choose(role)}"
            )
    return out


def _choose(role: str) -> str:
    """How a user names the topic of ``role``: ``svains run``/``compare``/``info`` take
    ``--topic ROLE=TOPIC``, ``svains convert`` ``--ROLE TOPIC``, every command the ``rostopic``
    of the Kalibr file that calibrates that sensor."""
    where = {"left": "cam0 in the camchain (--calib)", "right": "cam1 in the camchain (--calib)",
             "imu": "the imu.yaml (--imu-calib)"}.get(role)  # fmt: skip
    return (f"pass --topic {role}=TOPIC (run, compare, info, frontend; svains convert: --{role} "
            "TOPIC)") + (
        f", or give it as rostopic of {where}" if where else "")


def parse_topic_roles(text: str | None) -> dict[str, str | None] | None:
    """Topic per role from ``"imu=/imu0,left=/cam0/image_raw"`` (``replay.topics``,
    ``--topic``); None for None or empty. ``ConfigError`` naming an unknown role, a role given
    twice or an item without ``=``."""
    if not text or not text.strip():
        return None
    out: dict[str, str | None] = {}
    for item in text.split(","):
        role, eq, topic = item.strip().partition("=")
        role, topic = role.strip(), topic.strip()
        if not eq or not role or not topic:
            raise ConfigError(f"replay.topics (--topic): {item.strip()!r} is not ROLE=TOPIC "
                              f"(roles: {', '.join(ROLES)})")  # fmt: skip
        if role not in ROLES:
            raise ConfigError(f"replay.topics (--topic): unknown role {role!r} in "
                              f"{item.strip()!r} (roles: {', '.join(ROLES)})")  # fmt: skip
        if role in out:
            raise ConfigError(f"replay.topics (--topic): the {role} topic given twice "
                              f"({out[role]}, {topic})")  # fmt: skip
        out[role] = topic
    return out


def topic_roles_text(roles: dict[str, str | None]) -> str:
    """``roles`` (``parse_topic_roles``) as one spelling, in the roles' order."""
    return ",".join(f"{r}={roles[r]}" for r in ROLES if roles.get(r))


def select_topics(
    topics: list[TopicInfo],
    given: dict[str, str | None] | None = None,
    hints: dict[str, str] | None = None,
    roles: tuple[str, ...] = ROLES,
) -> dict[str, str]:
    """Topic per role (imu, left, right, gps, gt): ``given`` ones, checked; then ``hints`` (the
    calibration's ``rostopic``) when the bag has them with the right type; then auto-detected
    by message type (and for cameras by name: cam0/left, cam1/right) when unambiguous.

    A role with no candidate is left out; an ambiguous one raises ``ConfigError`` naming the
    candidates and the flag that chooses.
    """
    given = dict(given or {})
    by_name = {t.name: t for t in topics}
    out: dict[str, str] = {}
    for role, name in given.items():
        if not name:
            continue
        if name not in by_name:
            # named by topic and role: convert takes --gt, evaluate --ref-topic/--est-topic
            raise ConfigError(f"{name} (the {role} topic): no such topic in the bag (its "
                              f"topics: {', '.join(sorted(by_name)) or 'none'})")  # fmt: skip
        if by_name[name].msgtype not in ROLE_TYPES[role]:
            raise ConfigError(
                f"{name} (the {role} topic): type {by_name[name].msgtype} is not one of "
                f"{', '.join(ROLE_TYPES[role])}"
            )
        out[role] = name
        # a topic given for one role that the calibration's rostopic gives another: the
        # calibration would follow the wrong images (cam0's on the right camera: a user's
        # probe, silent)
        other = [r for r, n in (hints or {}).items() if n == name and r != role]
        if other:
            raise ConfigError(f"{name} (the {role} topic): the calibration's rostopic makes it "
                              f"the {other[0]} topic; give the roles the calibration gives, "
                              "or fix its rostopic")  # fmt: skip
    for role, name in (hints or {}).items():
        ok = name in by_name and by_name[name].msgtype in ROLE_TYPES[role]
        if role not in out and ok and name not in out.values():
            out[role] = name
    for role in ("imu", "gps", "gt"):
        if role in out or role not in roles:
            continue
        cands = [t.name for t in topics if t.msgtype in ROLE_TYPES[role]]
        if len(cands) == 1:
            out[role] = cands[0]
        elif len(cands) > 1:
            raise ConfigError(f"several {role} topics ({', '.join(cands)}): {_choose(role)}")
    images = [t.name for t in topics if t.msgtype in ROLE_TYPES["left"]]
    images = [n for n in images if n not in (out.get("left"), out.get("right"))]
    if "left" in roles and ("left" not in out or "right" not in out):
        out.update(_pick_stereo(images, out))  # type: ignore[arg-type]
    return {k: v for k, v in out.items() if k in roles}


def _stamp_ns(msg: Any, record_ns: int) -> int:
    h = getattr(msg, "header", None)
    if h is None:
        return record_ns
    s = int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return s if s > 0 else record_ns


def _messages(path: Path, topics: dict[str, str]) -> Iterator[tuple[str, int, Any]]:
    """(role, stamp ns, message) of the selected topics in record order."""
    role_of = {v: k for k, v in topics.items()}
    try:
        with _reader(path) as r:
            conns = [c for c in r.connections if c.topic in role_of]
            for c, t_ns, raw in r.messages(connections=conns):
                msg = r.deserialize(raw, c.msgtype)
                yield role_of[c.topic], _stamp_ns(msg, t_ns), msg
    except (DatasetError, ConfigError):
        raise
    except Exception as exc:
        raise _open_error(path, exc) from exc


def _sorted_unique(t: list[int], role: str, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Order (indices) that sorts stamps and drops repeated ones, with a warning."""
    t_ns = np.asarray(t, np.int64)
    order = np.argsort(t_ns, kind="stable")
    keep = np.r_[True, np.diff(t_ns[order]) > 0]
    if not keep.all():
        log.warning("%s (%s): %d repeated stamp(s) dropped", topic, role, int((~keep).sum()))
    return t_ns[order][keep], order[keep]


def _image_payload(msg: Any) -> tuple[Any, ...]:
    if hasattr(msg, "encoding"):
        return ("raw", msg.encoding, int(msg.height), int(msg.width), int(msg.step),
                bytes(msg.data))  # fmt: skip
    return ("compressed", bytes(msg.data))


def decode_image(payload: tuple[Any, ...]) -> np.ndarray:
    """8-bit grey (H, W) of a stored image message payload."""
    if payload[0] == "raw":
        return decode_raw(*payload[1:])
    return decode_compressed(payload[1])


def _pose(msg: Any) -> tuple[list[float], list[float]]:
    """(position xyz, quaternion wxyz) of any supported pose message."""
    if hasattr(msg, "transform"):
        p, q = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        p, q = pose.position, pose.orientation
    return [p.x, p.y, p.z], [q.w, q.x, q.y, q.z]


class _Collector:
    """Accumulates each role's messages, then builds the ``Dataset`` streams."""

    def __init__(self) -> None:
        self.t: dict[str, list[int]] = {r: [] for r in ROLES}
        self.rows: dict[str, list[Any]] = {r: [] for r in ROLES}

    def add(self, role: str, t_ns: int, msg: Any) -> None:
        if role == "imu":
            w, a = msg.angular_velocity, msg.linear_acceleration
            row: Any = (w.x, w.y, w.z, a.x, a.y, a.z)
        elif role in ("left", "right"):
            row = _image_payload(msg)
        elif role == "gps":
            if int(msg.status.status) < 0:  # STATUS_NO_FIX
                return
            cov = np.asarray(msg.position_covariance, float).reshape(3, 3)
            known = int(msg.position_covariance_type) > 0
            std = float(np.sqrt(np.mean(np.diag(cov)))) if known else 0.0
            row = (msg.latitude, msg.longitude, msg.altitude, std)
        else:
            row = _pose(msg)
        self.t[role].append(t_ns)
        self.rows[role].append(row)


def _fill_gps(ds: Dataset, t: np.ndarray, a: np.ndarray) -> None:
    """GPS stream and calibration from (lat deg, lon deg, alt m, position std m) rows."""
    origin = (float(a[0, 0]), float(a[0, 1]), float(a[0, 2]))
    p = geodetic_to_enu(a[:, 0], a[:, 1], a[:, 2], origin)
    # Position only. Velocities differenced from these fixes and fused as independent
    # measurements count the position noise twice: on the simulator (4 seeds, 60 s, 1.4 m
    # fixes at 1 Hz, ``ins``) position RMSE 5.12 m with them against 4.02 m without.
    ds.gps = GpsStream(t_ns=t, p_W_G=p, v_W_G=np.full_like(p, np.nan))
    pos_std = float(np.median(a[:, 3])) if np.all(a[:, 3] > 0) else DEFAULT_GPS_POSITION_STD_M
    dt_s = float(np.median(np.diff(t))) * 1e-9 if t.size > 1 else 1.0
    # velocity_noise_std: that of two fixes one period apart (the in-flight start's, only)
    vel_std = pos_std * np.sqrt(2.0) / dt_s
    ds.gps_calib = GpsCalib(np.zeros(3), 1.0 / dt_s, pos_std, float(vel_std))
    ds.extras["gps_enu_origin_lat_lon_alt"] = origin


def _fill(ds: Dataset, col: _Collector, topics: dict[str, str], bag: Path) -> None:
    for role in ROLES:
        if role not in topics or not col.t[role]:
            continue
        t, idx = _sorted_unique(col.t[role], role, topics[role])
        rows = [col.rows[role][i] for i in idx]
        if role == "imu":
            a = np.asarray(rows, float)
            ds.imu = ImuStream(t_ns=t, gyro_B=a[:, 0:3].copy(), accel_B=a[:, 3:6].copy())
        elif role in ("left", "right"):
            paths = tuple(Path(f"{bag}#{topics[role]}/{int(ti)}") for ti in t)
            store = dict(zip(paths, rows, strict=True))
            setattr(ds, role, ImageStream(t, paths, loader=lambda p, s=store: decode_image(s[p])))
        elif role == "gps":
            _fill_gps(ds, t, np.asarray(rows, float))
        else:
            p = np.asarray([r[0] for r in rows], float)
            q = np.asarray([r[1] for r in rows], float)
            ds.groundtruth = groundtruth_from_poses(t, p, q)


def read_bag(
    path: Path | str,
    topics: dict[str, str | None] | None = None,
    hints: dict[str, str] | None = None,
    roles: tuple[str, ...] = ROLES,
) -> Dataset:
    """A bag as an in-memory ``Dataset`` (no calibration; see ``apply_kalibr``).

    ``topics`` maps roles (imu, left, right, gps, gt) to topic names; ``hints`` are topics to
    prefer when present; other roles are auto-detected (``select_topics``); only ``roles`` are
    read. The chosen topics are kept in ``extras["bag_topics"]``.
    """
    path = Path(path)
    chosen = select_topics(bag_topics(path, rates=False), topics, hints, roles)
    if not chosen:
        raise DatasetError(f"{path}: no IMU, image, NavSatFix or pose topics")
    col = _Collector()
    for role, t_ns, msg in _messages(path, chosen):
        col.add(role, t_ns, msg)
    name = path.stem if path.is_file() else path.name
    ds = Dataset(root=path, name=name)
    _fill(ds, col, chosen, path)
    ds.extras["bag_topics"] = dict(chosen)
    return ds
