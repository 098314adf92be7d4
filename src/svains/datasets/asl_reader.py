"""Read the ASL/EuRoC layout, extended with gps0/mag0/sonar0/features0 (``docs/formats.md``).

Every stream is optional. CSVs are parsed eagerly (they are small) except ``features0``, parsed
on first access of ``Dataset.features``; images are only listed and checked for existence here,
decoded later by ``ImageStream.load``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from svains.datasets._image_io import read_grey
from svains.datasets._textio import (
    parse_floats,
    parse_timestamps,
    read_csv_rows,
    read_numeric_table,
    read_sensor_yaml,
    yaml_float,
    yaml_T_BS,
    yaml_vector,
)
from svains.datasets.completion import warn_if_incomplete
from svains.datasets.types import (
    DEFAULT_GRAVITY_W,
    CameraCalib,
    Dataset,
    FeatureStream,
    GpsCalib,
    GpsStream,
    GroundTruth,
    ImageStream,
    ImuCalib,
    ImuStream,
    MagCalib,
    MagStream,
    SonarCalib,
    SonarStream,
)
from svains.datasets.validate import (
    check_camera_calib,
    check_feature_disparity,
    check_gps_calib,
    check_gravity,
    check_image_size,
    check_imu_calib,
    check_mag_calib,
    check_number,
    check_quaternions,
    check_sonar_calib,
    check_stereo_rig,
    check_stereo_sync,
    check_stream_unit,
)
from svains.errors import CalibrationError, DatasetError
from svains.geometry.distortion import canonical_model, check_coefficients

log = logging.getLogger(__name__)

STREAM_FOLDERS = (
    "imu0",
    "cam0",
    "cam1",
    "state_groundtruth_estimate0",
    "gps0",
    "mag0",
    "sonar0",
    "features0",
)


def find_mav0(path: Path) -> Path | None:
    """The ``mav0`` folder of an ASL data set given its root or ``mav0`` itself, else None."""
    if (path / "mav0").is_dir():
        return path / "mav0"
    if (path / "body.yaml").is_file() or any((path / s).is_dir() for s in STREAM_FOLDERS):
        return path
    return None


def _rate(calib: dict[str, Any], path: Path, t_ns: np.ndarray) -> float:
    """``rate_hz`` of a sensor.yaml, else the median sample rate of the data."""
    if "rate_hz" in calib:
        return yaml_float(calib, "rate_hz", path)
    u = np.unique(t_ns)
    return float(1e9 / np.median(np.diff(u))) if u.size > 1 else 0.0


def _table(
    folder: Path, n_cols: int | tuple[int, ...], strict: bool = True, min_rows: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """``data.csv`` of a numeric stream: (t_ns (N,), values (N, n_cols - 1)), N >= min_rows
    (``n_cols`` a tuple: the layout the first row picks, ``_textio.read_csv_rows``)."""
    t, values, _ = read_numeric_table(folder / "data.csv", n_cols, strict, min_rows)
    return t, values


def read_imu(folder: Path, replaced: bool = False) -> tuple[ImuStream, ImuCalib | None]:
    """IMU folder: (samples, calibration); ``replaced``: a Kalibr imu.yaml replaces the
    calibration, so a folder without ``sensor.yaml`` gives None."""
    t, a = _table(folder, 7, min_rows=2)
    a = a[:, _imu_columns(folder / "data.csv")]
    stream = ImuStream(t_ns=t, gyro_B=a[:, 0:3], accel_B=a[:, 3:6])
    ypath = folder / "sensor.yaml"
    if not ypath.exists():
        if not replaced:
            raise DatasetError(f"missing file: {ypath} (the IMU's calibration; or give a "
                               "Kalibr imu.yaml: --imu-calib)")  # fmt: skip
        return stream, None
    y = read_sensor_yaml(ypath)
    calib = ImuCalib(
        T_B_S=yaml_T_BS(y, ypath),
        rate_hz=_rate(y, ypath, t),
        gyro_noise_density=yaml_float(y, "gyroscope_noise_density", ypath),
        gyro_random_walk=yaml_float(y, "gyroscope_random_walk", ypath),
        accel_noise_density=yaml_float(y, "accelerometer_noise_density", ypath),
        accel_random_walk=yaml_float(y, "accelerometer_random_walk", ypath),
        gyro_range=yaml_float(y, "gyroscope_range", ypath) if "gyroscope_range" in y else None,
        accel_range=(
            yaml_float(y, "accelerometer_range", ypath) if "accelerometer_range" in y else None
        ),
    )
    check_imu_calib(calib, ypath)
    return stream, calib


def _imu_columns(path: Path) -> list[int]:
    """The order (6,) that puts an IMU ``data.csv``'s value columns as gyro x y z, accelerometer
    x y z: EuRoC's order, or the one its header names (``w_RS_S_x`` … ``a_RS_S_z``, or any
    names starting ``w_``/``gyro`` and ``a_``/``acc`` and ending in the axis) when it has
    one naming all six."""
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        first = fh.readline().strip()
    if not (first.startswith("#") or first[:1].isalpha()):  # a header, with or without '#'
        return list(range(6))
    names = [f.strip().lower().split(" ")[0] for f in first.lstrip("#").split(",")[1:]]
    order: list[int] = []
    for kind in (("w_", "gyro"), ("a_", "acc")):
        for axis in "xyz":
            hits = [i for i, n in enumerate(names) if n.startswith(kind) and n.endswith(axis)]
            if len(hits) != 1:
                return list(range(6))
            order.append(hits[0])
    if sorted(order) != list(range(6)):
        return list(range(6))
    if order != list(range(6)):
        log.info("%s: columns read by the header's names (%s)", path, ", ".join(names))
    return order


def read_camera_calib(folder: Path, t_ns: np.ndarray | None = None) -> CameraCalib:
    """Kalibr pinhole ``sensor.yaml`` of a camera folder: radial-tangential (4 or 5
    coefficients, OpenCV order k1 k2 p1 p2 [k3]) or equidistant (k1..k4) distortion, and the
    optional ``timeshift_cam_imu`` (s, Kalibr's: t_imu = t_cam + timeshift)."""
    ypath = folder / "sensor.yaml"
    y = read_sensor_yaml(ypath)
    if "intrinsics" not in y:
        raise CalibrationError(f"{ypath}: camera calibration without 'intrinsics' [fu, fv, cu, cv]")
    model = str(y.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise CalibrationError(f"{ypath}: camera_model '{model}' is not supported (pinhole only)")
    dist_model = str(y.get("distortion_model", "radial-tangential"))
    # Kalibr's camchain names them ``distortion_coeffs``; a sensor.yaml written from one
    # carried its lens as undistorted, under a warning only (a user's probe)
    key = next((k for k in ("distortion_coefficients", "distortion_coeffs")
                if y.get(k) is not None), None)  # fmt: skip
    if key is None:
        log.warning("%s: no 'distortion_coefficients': the lens is taken as undistorted (write "
                    "[0.0, 0.0, 0.0, 0.0] to say so)", ypath)  # fmt: skip
    try:
        canonical = canonical_model(dist_model)
        dist = check_coefficients(canonical, y[key]) if key is not None else np.zeros(4)
    except (CalibrationError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{ypath}: {exc}") from exc
    res = yaml_vector(y, "resolution", ypath, 2)
    shift = yaml_float(y, "timeshift_cam_imu", ypath, default=0.0)
    if not np.isfinite(shift):
        raise CalibrationError(f"{ypath}: field 'timeshift_cam_imu' must be finite, is {shift}")
    calib = CameraCalib(
        name=folder.name,
        T_B_C=yaml_T_BS(y, ypath),
        rate_hz=_rate(y, ypath, t_ns if t_ns is not None else np.zeros(0, np.int64)),
        resolution=(int(res[0]), int(res[1])),
        intrinsics=yaml_vector(y, "intrinsics", ypath, 4),
        distortion_model=dist_model,
        distortion=dist,
        timeshift_cam_imu_s=shift,
    )
    check_camera_calib(calib, ypath)
    return calib


def read_image_list(folder: Path) -> tuple[ImageStream, np.ndarray, int]:
    """Camera ``data.csv``: (images present on disk, every listed time, number absent), on the
    camera's own clock (``read_camera`` moves them to the IMU clock)."""
    path = folder / "data.csv"
    rows, lines = read_csv_rows(path, 2)
    t = parse_timestamps(path, rows, lines)
    data = folder / "data"
    on_disk = set(os.listdir(data)) if data.is_dir() else set()
    keep = np.array([r[1] in on_disk for r in rows], dtype=bool)
    paths = tuple(data / r[1] for r, k in zip(rows, keep, strict=True) if k)
    return ImageStream(t_ns=t[keep], paths=paths, loader=read_grey), t, int((~keep).sum())


def read_camera(folder: Path, replaced: bool = False
                ) -> tuple[ImageStream, CameraCalib | None, int]:  # fmt: skip
    """Camera folder: (images present on disk, calibration, number of listed-but-absent files);
    ``replaced``: a Kalibr camchain replaces the calibration, so a folder without
    ``sensor.yaml`` gives None (the stamps as recorded).

    Stamps move to the IMU clock once, here: t_imu = t_cam + ``timeshift_cam_imu``."""
    stream, t, n_missing = read_image_list(folder)
    if not (folder / "sensor.yaml").exists():
        if not replaced:
            raise DatasetError(f"missing file: {folder / 'sensor.yaml'} (the camera's "
                               "calibration; or give a Kalibr camchain: --calib)")  # fmt: skip
        return stream, None, n_missing
    calib = read_camera_calib(folder, t)
    check_image_size(stream, calib, folder / "sensor.yaml")
    return shift_image_stamps(stream, calib.timeshift_cam_imu_s), calib, n_missing


def shift_image_stamps(stream: ImageStream, timeshift_cam_imu_s: float) -> ImageStream:
    """``stream`` with its stamps moved from the camera clock to the IMU clock."""
    shift_ns = np.int64(round(timeshift_cam_imu_s * 1e9))
    return stream if shift_ns == 0 else replace(stream, t_ns=stream.t_ns + shift_ns)


def read_groundtruth(folder: Path) -> GroundTruth:
    t, a = _table(folder, 17)
    check_quaternions(t, a[:, 3:7], folder / "data.csv")
    return GroundTruth(
        t_ns=t, p_W_B=a[:, 0:3], q_W_B_wxyz=a[:, 3:7], v_W_B=a[:, 7:10], bg_B=a[:, 10:13],
        ba_B=a[:, 13:16],
    )  # fmt: skip


def read_gps(folder: Path) -> tuple[GpsStream, GpsCalib]:
    """GPS folder: fixes on the IMU clock (``t_imu = t_gps + timeshift_gps_imu``, an optional
    key, s) and calibration. Rows of 7 fields carry position and velocity; rows of 4 fields
    position only (a receiver that gives no velocity, NMEA GGA): their velocities are NaN and
    ``velocity_noise_std`` may be left out (then that of two fixes differenced one period
    apart, ``√2 σ_p · rate``, which only the in-flight start uses)."""
    t, a = _table(folder, (7, 4))
    ypath = folder / "sensor.yaml"
    y = read_sensor_yaml(ypath)
    shift = yaml_float(y, "timeshift_gps_imu", ypath, default=0.0)
    if not np.isfinite(shift):
        raise CalibrationError(f"{ypath}: field 'timeshift_gps_imu' must be finite, is {shift}")
    rate_hz = _rate(y, ypath, t)
    sigma_p = yaml_float(y, "position_noise_std", ypath)
    with_velocity = a.shape[1] == 6
    if with_velocity or "velocity_noise_std" in y:
        sigma_v = yaml_float(y, "velocity_noise_std", ypath)
    else:
        sigma_v = float(np.sqrt(2.0) * sigma_p * (rate_hz if rate_hz > 0 else 1.0))
    calib = GpsCalib(
        p_B_G=yaml_T_BS(y, ypath)[:3, 3].copy(),
        rate_hz=rate_hz,
        position_noise_std=sigma_p,
        velocity_noise_std=sigma_v,
        timeshift_gps_imu_s=shift,
        position_correlation_s=yaml_float(y, "position_correlation_s", ypath, default=0.0),
    )
    check_gps_calib(calib, ypath)
    t_imu = t + np.int64(round(shift * 1e9))
    v = a[:, 3:6] if with_velocity else np.full((len(t), 3), np.nan)
    return GpsStream(t_ns=t_imu, p_W_G=a[:, 0:3], v_W_G=v), calib


def read_mag(folder: Path) -> tuple[MagStream, MagCalib]:
    t, a = _table(folder, 4)
    ypath = folder / "sensor.yaml"
    y = read_sensor_yaml(ypath)
    calib = MagCalib(
        T_B_S=yaml_T_BS(y, ypath),
        rate_hz=_rate(y, ypath, t),
        m_W=yaml_vector(y, "reference_field_W", ypath, 3),
        noise_std=yaml_float(y, "noise_std", ypath),
    )
    check_mag_calib(calib, ypath)
    return MagStream(t_ns=t, m_S=a), calib


def read_sonar(folder: Path) -> tuple[SonarStream, SonarCalib]:
    t, a = _table(folder, 2)
    ypath = folder / "sensor.yaml"
    y = read_sensor_yaml(ypath)
    calib = SonarCalib(
        T_B_S=yaml_T_BS(y, ypath),
        rate_hz=_rate(y, ypath, t),
        noise_std=yaml_float(y, "noise_std", ypath),
        ground_height=yaml_float(y, "ground_height", ypath, default=0.0),
    )
    check_sonar_calib(calib, ypath)
    return SonarStream(t_ns=t, range_m=a[:, 0]), calib


def read_features(folder: Path, timeshift_cam_imu_s: float = 0.0) -> FeatureStream:
    """``features0``: rows share a frame's timestamp, so times need only be non-decreasing.

    Its frames are cam0/cam1 frames, stamped on the cameras' clock as their images are: the
    stamps move to the IMU clock by cam0's ``timeshift_cam_imu_s`` (s) here, as the images'
    do in ``read_camera``."""
    path = folder / "data.csv"
    t, values, lines = read_numeric_table(path, 6, strict=False)
    ids_f = values[:, 0]
    not_int = (ids_f != np.round(ids_f)) | (np.abs(ids_f) >= 2.0**53)
    if np.any(not_int):
        k = lines[int(np.flatnonzero(not_int)[0])]
        raise DatasetError(f"{path}:{k}: track_id must be an integer (below 2^53)")
    ids = ids_f.astype(np.int64)
    uv = values[:, 1:5]
    check_stream_unit(t, "camera pair", path)
    if t.size > 1:
        order = np.lexsort((ids, t))
        dup = np.flatnonzero((np.diff(t[order]) == 0) & (np.diff(ids[order]) == 0))
        if dup.size:
            i = int(order[dup[0] + 1])
            raise DatasetError(
                f"{path}:{lines[i]}: duplicate observation of track {ids[i]} at {t[i]}"
            )
    ypath = folder / "sensor.yaml"
    y = read_sensor_yaml(ypath) if ypath.is_file() else {}
    pixel_std = yaml_float(y, "pixel_noise_std", ypath, default=1.0)
    check_number(pixel_std, ypath, "pixel_noise_std", positive=True)
    check_feature_disparity(uv[:, 0:2], uv[:, 2:4], pixel_std, path)
    return shift_feature_stamps(
        FeatureStream(t_ns=t, track_id=ids, uv_left=uv[:, 0:2], uv_right=uv[:, 2:4],
                      pixel_noise_std=pixel_std),
        round(timeshift_cam_imu_s * 1e9),
    )  # fmt: skip


def shift_feature_stamps(stream: FeatureStream, shift_ns: int) -> FeatureStream:
    """``stream`` with its frame stamps moved by ``shift_ns`` (ns)."""
    return stream if shift_ns == 0 else replace(stream, t_ns=stream.t_ns + np.int64(shift_ns))


def _read_extras(folder: Path) -> dict[str, object]:
    """Simulator extras beside the ground truth (kinematics.csv, landmarks.csv, scenario.yaml).

    They are optional diagnostics: a malformed one is skipped with a warning naming the error
    rather than making the whole data set unreadable.
    """
    extras: dict[str, object] = {}
    kin = folder / "kinematics.csv"
    lm = folder / "landmarks.csv"
    try:
        if kin.is_file():
            rows, lines = read_csv_rows(kin, 13)
            t = parse_timestamps(kin, rows, lines)
            a = parse_floats(kin, rows, lines, slice(1, None))
            extras["kinematics"] = {
                "t_ns": t, "omega_B": a[:, 0:3], "alpha_B": a[:, 3:6], "a_W": a[:, 6:9],
                "f_B": a[:, 9:12],
            }  # fmt: skip
        if lm.is_file():
            rows, lines = read_csv_rows(lm, 4)
            a = parse_floats(lm, rows, lines, slice(1, None))
            ids = parse_floats(lm, rows, lines, slice(0, 1))[:, 0].astype(np.int64)
            extras["landmarks"] = {"id": ids, "p_W_F": a}
    except DatasetError as exc:
        log.warning("simulator extra skipped: %s", exc)
    if (folder / "scenario.yaml").is_file():
        extras["scenario_path"] = folder / "scenario.yaml"
    return extras


def _check_stereo(ds: Dataset, mav0: Path) -> None:
    """Both cameras: a real baseline, and left/right stamps paired within the tolerance."""
    if ds.cam0 is not None and ds.cam1 is not None:
        check_stereo_rig(ds.cam0, ds.cam1, mav0 / "cam0/sensor.yaml", mav0 / "cam1/sensor.yaml")
    if ds.left is not None and ds.right is not None:
        where = f"{mav0 / 'cam0/data.csv'}, {mav0 / 'cam1/data.csv'}"
        check_stereo_sync(ds.left, ds.right, ds.stereo_tol_ns, where)


# EuRoC's own folders that svains does not read (its positions, point clouds, motion capture)
_OTHER_KNOWN = frozenset({"leica0", "vicon0", "pointcloud0", "mocap0"})


def _warn_unknown_folders(mav0: Path) -> None:
    """Warn about stream folders that are not read when a sensor's usual one is missing
    (``imu/``, ``left/``, ``right/`` exported from a bag: ``info`` listed the ground truth alone
    and said nothing; a user's probe)."""
    others = sorted(f.name for f in mav0.iterdir() if f.is_dir() and f.name not in STREAM_FOLDERS
                    and f.name not in _OTHER_KNOWN and not f.name.startswith("."))  # fmt: skip
    missing = [n for n in ("imu0", "cam0", "cam1") if not (mav0 / n).is_dir()]
    if others and missing:
        log.warning("%s: folder(s) %s are not read: the streams are read from imu0/, cam0/ "
                    "(left), cam1/ (right), gps0/, mag0/, sonar0/, features0/ and "
                    "state_groundtruth_estimate0/ (%s missing here); rename them",
                    mav0, ", ".join(f"{n}/" for n in others),
                    ", ".join(f"{n}/" for n in missing))  # fmt: skip


def read_asl(path: Path, replaced: frozenset[str] = frozenset()) -> Dataset:
    """Read an ASL data set (root folder or its ``mav0``); absent streams stay ``None``.
    ``replaced``: the calibrations Kalibr files replace (``"cameras"``, ``"imu"``), whose
    ``sensor.yaml`` may then be absent (its calibration None until they are applied)."""
    mav0 = find_mav0(path)
    if mav0 is None:
        raise DatasetError(f"{path}: not an ASL data set (no mav0/ or stream folders)")
    root = mav0.parent if mav0.name == "mav0" else mav0
    ds = Dataset(root=root, name=root.name)
    _warn_unknown_folders(mav0)
    body = mav0 / "body.yaml"
    if body.is_file():
        y = read_sensor_yaml(body)
        if "gravity_W" in y:
            ds.gravity_W = yaml_vector(y, "gravity_W", body, 3)
            check_gravity(ds.gravity_W, body)
        if "stereo_pair_tolerance_ns" in y:
            tol = yaml_float(y, "stereo_pair_tolerance_ns", body)
            check_number(tol, body, "stereo_pair_tolerance_ns", non_negative=True)
            ds.stereo_tol_ns = int(tol)
    else:
        ds.gravity_W = np.array(DEFAULT_GRAVITY_W)
    if (mav0 / "imu0").is_dir():
        ds.imu, ds.imu_calib = read_imu(mav0 / "imu0", "imu" in replaced)
    missing: dict[str, int] = {}
    for cam, attr in (("cam0", "left"), ("cam1", "right")):
        if (mav0 / cam).is_dir():
            stream, calib, n_missing = read_camera(mav0 / cam, "cameras" in replaced)
            setattr(ds, attr, stream)
            setattr(ds, cam, calib)
            if n_missing:
                missing[cam] = n_missing
    gt = mav0 / "state_groundtruth_estimate0"
    if gt.is_dir():
        ds.groundtruth = read_groundtruth(gt)
        ds.extras.update(_read_extras(gt))
    if (mav0 / "gps0").is_dir():
        ds.gps, ds.gps_calib = read_gps(mav0 / "gps0")
    if (mav0 / "mag0").is_dir():
        ds.mag, ds.mag_calib = read_mag(mav0 / "mag0")
    if (mav0 / "sonar0").is_dir():
        ds.sonar, ds.sonar_calib = read_sonar(mav0 / "sonar0")
    if (mav0 / "features0").is_dir():
        # Parsed on first access: a run from images never needs it (seconds for a long set).
        # A partial, not a lambda: the data set stays picklable.
        shift = ds.cam0.timeshift_cam_imu_s if ds.cam0 is not None else 0.0
        ds.defer("features", partial(read_features, mav0 / "features0", shift))
    _check_stereo(ds, mav0)
    warn_if_incomplete(mav0)
    ds.missing_images = missing
    if missing:
        # One warning for the whole data set: the frames are skipped, the count is kept.
        detail = ", ".join(f"{k}: {v}" for k, v in missing.items())
        log.warning(
            "%s: %d image(s) listed in data.csv but absent on disk, skipped (%s)",
            root, sum(missing.values()), detail,
        )  # fmt: skip
    return ds
