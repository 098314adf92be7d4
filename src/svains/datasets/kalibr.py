"""Kalibr calibration files: ``camchain-imucam.yaml`` (cameras) and ``imu.yaml`` (IMU noise).

The mapping to svains (also in ``docs/formats.md``):

- body frame B = the IMU frame of ``imu.yaml`` (Kalibr's ``imu0``); when only a camchain is given,
  the data set's own IMU ``T_B_S`` places the IMU on the body (identity if it has none);
- ``T_cam_imu`` (Kalibr) maps IMU points into the camera, so ``T_B_C = T_B_I inv(T_cam_imu)``;
  OpenVINS' ``T_imu_cam`` is ``T_I_C`` directly; a camera with neither gets
  ``T_cn_cnm1`` chained onto the previous camera (``T_I_Cn = T_I_Cnm1 inv(T_cn_cnm1)``);
- ``timeshift_cam_imu`` [s]: ``t_imu = t_cam + timeshift``, so image times are shifted by it;
- ``intrinsics`` ``[fu, fv, pu, pv]``, ``resolution`` ``[w, h]``; ``distortion_model``
  ``radtan`` (4 coefficients, or 5 with k3) -> ``"radtan"``, ``equidistant`` (4, Kannala-Brandt)
  -> ``"equidistant"``, ``none`` -> ``"radtan"`` with zeros; only ``camera_model: pinhole``;
- ``imu.yaml``: ``gyroscope_noise_density`` ... ``accelerometer_random_walk`` and
  ``update_rate``, at the top level or under ``imu0:``; ``T_i_b`` (body to this IMU) if present.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from svains.datasets._textio import format_float, read_sensor_yaml, yaml_float
from svains.datasets.asl_reader import shift_feature_stamps
from svains.datasets.types import CameraCalib, Dataset, ImageStream, ImuCalib
from svains.datasets.validate import (
    check_camera_calib,
    check_image_size,
    check_stereo_rig,
    check_timeshift,
    make_orthonormal,
)
from svains.errors import CalibrationError

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

# Kalibr distortion model -> (svains name, allowed coefficient counts).
DISTORTION_MODELS: dict[str, tuple[str, tuple[int, ...]]] = {
    "radtan": ("radtan", (4, 5)),
    "equidistant": ("equidistant", (4,)),
    "none": ("radtan", (0, 4)),
}
IMU_NOISE_KEYS = (
    ("gyro_noise_density", "gyroscope_noise_density"),
    ("gyro_random_walk", "gyroscope_random_walk"),
    ("accel_noise_density", "accelerometer_noise_density"),
    ("accel_random_walk", "accelerometer_random_walk"),
)


@dataclass(frozen=True)
class KalibrChain:
    """Cameras of a camchain in file order, ``T_B_C`` = camera to IMU (``T_I_C``).

    ``timeshift_cam_imu_s``: cam0's ``t_imu - t_cam`` [s]; ``rostopics``: per camera or None.
    """

    cameras: tuple[CameraCalib, ...]
    timeshift_cam_imu_s: float
    rostopics: tuple[str | None, ...]
    # cam0 came with a camera-IMU transform (False: a plain camchain, cam0 at identity)
    has_imu_transform: bool = True


def _matrix4(node: Any, key: str, path: Path) -> F64:
    """A 4x4 from Kalibr's list of 4 rows (or 16 numbers, or an EuRoC ``data:`` block)."""
    values = node.get("data") if isinstance(node, dict) else node
    try:
        T = np.asarray(values, dtype=float).reshape(4, 4)
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: '{key}' must be a 4x4 matrix (4 rows of 4)") from None
    if not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise CalibrationError(f"{path}: '{key}' is not a homogeneous transform: last row {T[3]}")
    make_orthonormal(T, path, key)  # the tolerance and projection of sensor.yaml's T_BS
    return T


def _numbers(cam: dict[str, Any], key: str, path: Path, where: str) -> F64:
    if key not in cam:
        raise CalibrationError(f"{path}: {where} has no '{key}'")
    try:
        return np.asarray([float(v) for v in cam[key]], dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: {where} '{key}' must be a list of numbers") from None


def _camera(cam: dict[str, Any], name: str, path: Path, T_I_C: F64) -> CameraCalib:
    model = str(cam.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise CalibrationError(
            f"{path}: {name} camera_model '{model}' is not supported (pinhole only)"
        )
    kalibr_dist = str(cam.get("distortion_model", "none"))
    if kalibr_dist not in DISTORTION_MODELS:
        raise CalibrationError(
            f"{path}: {name} distortion_model '{kalibr_dist}' is not supported "
            f"(expected one of {', '.join(DISTORTION_MODELS)})"
        )
    dist_model, counts = DISTORTION_MODELS[kalibr_dist]
    has_coeffs = "distortion_coeffs" in cam
    coeffs = _numbers(cam, "distortion_coeffs", path, name) if has_coeffs else np.zeros(0)
    if coeffs.size not in counts:
        raise CalibrationError(
            f"{path}: {name} {kalibr_dist} needs {' or '.join(map(str, counts))} "
            f"distortion_coeffs, has {coeffs.size}"
        )
    intr = _numbers(cam, "intrinsics", path, name)
    res = _numbers(cam, "resolution", path, name)
    if intr.size != 4 or res.size != 2:
        raise CalibrationError(
            f"{path}: {name} needs intrinsics [fu, fv, pu, pv] and resolution [w, h]"
        )
    cal = CameraCalib(
        name=name, T_B_C=T_I_C, rate_hz=0.0, resolution=(int(res[0]), int(res[1])),
        intrinsics=intr, distortion_model=dist_model,
        distortion=coeffs if coeffs.size else np.zeros(4),
    )  # fmt: skip
    check_camera_calib(cal, Path(path))  # as a sensor.yaml's: intrinsics order, lens model
    return cal


def read_camchain(path: Path | str) -> KalibrChain:
    """Parse a Kalibr ``camchain-imucam.yaml`` (or a plain ``camchain.yaml``, or OpenVINS'
    ``kalibr_imucam_chain.yaml`` with ``T_imu_cam``); cameras ``cam0``, ``cam1``, ... in order.

    A plain camchain without any IMU transform puts the IMU at cam0 (``T_I_C0`` = identity,
    ``has_imu_transform`` False; ``apply_kalibr`` then places the cameras through the data
    set's cam0). A ``timeshift_cam_imu`` beyond ``MAX_TIMESHIFT_S`` is refused.
    """
    path = Path(path)
    y = read_sensor_yaml(path)
    names = sorted(
        (k for k in y if k.startswith("cam") and k[3:].isdigit()), key=lambda k: int(k[3:])
    )
    if not names:
        raise CalibrationError(f"{path}: no camera entries (expected 'cam0:', 'cam1:', ...)")
    cams: list[CameraCalib] = []
    topics: list[str | None] = []
    shift = 0.0
    for i, name in enumerate(names):
        c = y[name]
        if not isinstance(c, dict):
            raise CalibrationError(f"{path}: '{name}' must be a mapping")
        if "T_cam_imu" in c:
            T_I_C = np.linalg.inv(_matrix4(c["T_cam_imu"], f"{name}.T_cam_imu", path))
        elif "T_imu_cam" in c:
            T_I_C = _matrix4(c["T_imu_cam"], f"{name}.T_imu_cam", path)
        elif i > 0 and "T_cn_cnm1" in c:
            T_cn_cnm1 = _matrix4(c["T_cn_cnm1"], f"{name}.T_cn_cnm1", path)
            T_I_C = cams[-1].T_B_C @ np.linalg.inv(T_cn_cnm1)
        elif i == 0:
            T_I_C = np.eye(4)
        else:
            raise CalibrationError(f"{path}: {name} has none of T_cam_imu, T_imu_cam, T_cn_cnm1")
        if i > 0 and "T_cn_cnm1" in c and ("T_cam_imu" in c or "T_imu_cam" in c):
            _check_chain(T_I_C, cams[-1].T_B_C, _matrix4(c["T_cn_cnm1"], f"{name}.T_cn_cnm1",
                                                          path), name, path)  # fmt: skip
        cams.append(_camera(c, name, path, T_I_C))
        topics.append(str(c["rostopic"]) if "rostopic" in c else None)
        if i == 0:
            shift = yaml_float(c, "timeshift_cam_imu", path, default=0.0)
            check_timeshift(shift, path, f"{name}.timeshift_cam_imu")
        elif "timeshift_cam_imu" in c:
            own = yaml_float(c, "timeshift_cam_imu", path)
            if abs(own - shift) > TIMESHIFT_AGREE_S:
                # the pair is taken as triggered together: cam0's offset moves both
                log.warning("%s: %s.timeshift_cam_imu %.2f ms differs from cam0's %.2f ms: "
                            "cam0's is applied to both (a stereo pair shares one stamp)", path,
                            name, own * 1e3, shift * 1e3)  # fmt: skip
    has_imu = any(k in y[names[0]] for k in ("T_cam_imu", "T_imu_cam"))
    return KalibrChain(tuple(cams), shift, tuple(topics), has_imu)


# A camera's T_cam_imu and its T_cn_cnm1 chained onto the camera before agree this closely, and
# cameras' timeshifts (Kalibr writes both from one solution: they agree to its print precision).
CHAIN_AGREE_DEG = 0.05
CHAIN_AGREE_M = 1e-3
TIMESHIFT_AGREE_S = 1e-3


def _check_chain(T_I_C: F64, T_I_Cprev: F64, T_cn_cnm1: F64, name: str, path: Path) -> None:
    """Warn when ``name``'s T_cam_imu (``T_I_C``, used) and its T_cn_cnm1 chained onto the
    camera before disagree (a camchain edited by hand, half of it from another calibration)."""
    chained = T_I_Cprev @ np.linalg.inv(T_cn_cnm1)
    D = np.linalg.inv(chained) @ T_I_C
    angle = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
    dist = float(np.linalg.norm(D[:3, 3]))
    if angle > CHAIN_AGREE_DEG or dist > CHAIN_AGREE_M:
        log.warning("%s: %s's T_cam_imu and its T_cn_cnm1 disagree by %.2f° and %.1f mm: "
                    "T_cam_imu is used; is one of them from another calibration?", path, name,
                    angle, dist * 1e3)  # fmt: skip


def read_kalibr_imu(path: Path | str) -> tuple[ImuCalib, str | None]:
    """Kalibr/OpenVINS ``imu.yaml``: (``ImuCalib`` with ``T_B_S`` = inv(``T_i_b``), rostopic)."""
    path = Path(path)
    y = read_sensor_yaml(path)
    if "imu0" in y and isinstance(y["imu0"], dict):
        y = y["imu0"]
    vals = {ours: yaml_float(y, theirs, path) for ours, theirs in IMU_NOISE_KEYS}
    for ours, v in vals.items():
        if v <= 0.0:
            raise CalibrationError(f"{path}: {dict(IMU_NOISE_KEYS)[ours]} must be positive")
    T_B_S = np.linalg.inv(_matrix4(y["T_i_b"], "T_i_b", path)) if "T_i_b" in y else np.eye(4)
    rate = yaml_float(y, "update_rate", path, default=0.0)
    topic = str(y["rostopic"]) if "rostopic" in y else None
    return ImuCalib(T_B_S=T_B_S, rate_hz=rate, **vals), topic


def kalibr_topics(camchain_path: Path | str | None, imu_path: Path | str | None) -> dict[str, str]:
    """Bag topics the Kalibr files name (``rostopic``): roles ``left``, ``right``, ``imu``."""
    out: dict[str, str] = {}
    if camchain_path is not None:
        chain = read_camchain(camchain_path)
        for role, topic in zip(("left", "right"), chain.rostopics, strict=False):
            if topic:
                out[role] = topic
    if imu_path is not None:
        topic = read_kalibr_imu(imu_path)[1]
        if topic:
            out["imu"] = topic
    return out


def _shift_images(stream: ImageStream | None, shift_ns: int) -> ImageStream | None:
    if stream is None or shift_ns == 0:
        return stream
    return dataclasses.replace(stream, t_ns=np.asarray(stream.t_ns, np.int64) + shift_ns)


def _shift_features(ds: Dataset, out: Dataset, shift_ns: int) -> None:
    """``out.features``: ``ds``'s feature frames (cam0/cam1 frames, on the cameras' clock as
    their images) moved by ``shift_ns``."""
    if shift_ns != 0 and ds.features is not None:
        out.features = shift_feature_stamps(ds.features, shift_ns)


def _with_rate(
    cal: CameraCalib, stream: ImageStream | None, old: CameraCalib | None
) -> CameraCalib:
    """Kalibr has no camera rate: keep the data set's, else the median rate of the images."""
    if old is not None and old.rate_hz > 0:
        return dataclasses.replace(cal, rate_hz=old.rate_hz)
    if stream is not None and len(stream) > 1:
        return dataclasses.replace(cal, rate_hz=float(1e9 / np.median(np.diff(stream.t_ns))))
    return cal


def apply_kalibr(
    ds: Dataset, camchain_path: Path | str | None = None, imu_path: Path | str | None = None
) -> Dataset:
    """A copy of ``ds`` whose calibration comes from Kalibr files (either may be None).

    ``imu.yaml`` replaces the IMU calibration (the IMU becomes the body frame unless it has a
    ``T_i_b``); the camchain replaces cam0/cam1, placed on the body through the IMU's ``T_B_S``,
    and shifts image times by ``timeshift_cam_imu`` (recorded in ``extras``).
    """
    out = dataclasses.replace(ds, extras=dict(ds.extras))
    if imu_path is not None:
        imu_cal, _ = read_kalibr_imu(imu_path)
        if imu_cal.rate_hz <= 0 and ds.imu_calib is not None:
            imu_cal = dataclasses.replace(imu_cal, rate_hz=ds.imu_calib.rate_hz)
        out.imu_calib = imu_cal
        out.extras["kalibr_imu"] = str(imu_path)
    if camchain_path is None:
        return out
    chain = read_camchain(camchain_path)
    if len(chain.cameras) < 2:
        raise CalibrationError(f"{camchain_path}: stereo needs two cameras, found 1")
    if len(chain.cameras) > 2:
        log.warning("%s: %d cameras, using cam0 and cam1", camchain_path, len(chain.cameras))
    T_B_I = out.imu_calib.T_B_S if out.imu_calib is not None else np.eye(4)
    if not chain.has_imu_transform:
        # A camera-only camchain: cam0 at the IMU with no rotation was taken silently (a rig
        # turned 90°: 210 m from images, 858 m from features, a user's probe). The cameras go
        # where the data set's cam0 is, the camchain giving their intrinsics and cam1's place.
        if ds.cam0 is None:
            raise CalibrationError(
                f"{camchain_path}: no camera-IMU transform (T_cam_imu) and the data set has no "
                "cam0 T_BS to place the cameras with: give Kalibr's camchain-imucam.yaml")
        log.warning("%s: no camera-IMU transform (T_cam_imu; a camera-only camchain): the "
                    "cameras are placed through the data set's cam0 T_BS", camchain_path)
        T_B_I = ds.cam0.T_B_C
    # Each camera's own sensor.yaml offset (if it has one) was applied at read time: replace it
    # (a folder with one camera's sensor.yaml and not the other's moved them apart: a
    # reviewer's case).
    def applied_s(cam: CameraCalib | None) -> float:
        return cam.timeshift_cam_imu_s if cam is not None else 0.0

    shift_ns = round((chain.timeshift_cam_imu_s - applied_s(ds.cam0)) * 1e9)
    out.left = _shift_images(ds.left, shift_ns)
    out.right = _shift_images(ds.right,
                              round((chain.timeshift_cam_imu_s - applied_s(ds.cam1)) * 1e9))
    _shift_features(ds, out, shift_ns)
    cams = [
        dataclasses.replace(
            c, T_B_C=T_B_I @ c.T_B_C, timeshift_cam_imu_s=chain.timeshift_cam_imu_s
        )
        for c in chain.cameras[:2]
    ]
    out.cam0 = _with_rate(cams[0], out.left, ds.cam0)
    out.cam1 = _with_rate(cams[1], out.right, ds.cam1)
    # the baseline's size, as for a sensor.yaml (extrinsics in mm ran to 452 m: a user's probe)
    check_stereo_rig(out.cam0, out.cam1, Path(camchain_path), Path(camchain_path))
    # refused here, as a sensor.yaml's is: every pair was dropped one by one during the run
    for stream, cal in ((out.left, out.cam0), (out.right, out.cam1)):
        if stream is not None:
            check_image_size(stream, cal, Path(camchain_path), decode=True)
    out.extras["kalibr_camchain"] = str(camchain_path)
    out.extras["timeshift_cam_imu_ns"] = shift_ns
    return out


def _yaml_list(v: F64 | list[float]) -> str:
    return "[" + ", ".join(format_float(float(x)) for x in np.asarray(v).reshape(-1)) + "]"


def _yaml_matrix(T: F64, indent: str) -> list[str]:
    return [f"{indent}- {_yaml_list(row)}" for row in np.asarray(T, float).reshape(4, 4)]


def write_camchain(
    path: Path | str,
    cameras: list[CameraCalib] | tuple[CameraCalib, ...],
    T_B_I: F64 | None = None,
    timeshift_cam_imu_s: float = 0.0,
    rostopics: list[str] | None = None,
    openvins: bool = False,
    comments: list[str] | None = None,
) -> Path:
    """Write cameras (``T_B_C`` on body B) as a Kalibr camchain-imucam (``T_cam_imu``, with
    ``T_cn_cnm1``), or with ``openvins`` as OpenVINS' ``T_imu_cam``; the IMU sits at ``T_B_I``.
    ``comments``: lines written first as YAML comments (readers ignore them)."""
    path = Path(path)
    T_I_B = np.linalg.inv(np.eye(4) if T_B_I is None else np.asarray(T_B_I, float))
    lines: list[str] = [f"# {c}" for c in comments or []]
    prev: F64 | None = None
    for i, cam in enumerate(cameras):
        T_I_C = T_I_B @ np.asarray(cam.T_B_C, float)
        kalibr_dist = (
            "radtan"
            if cam.distortion_model in ("radtan", "radial-tangential")
            else (cam.distortion_model)
        )
        lines.append(f"cam{i}:")
        if openvins:
            lines += ["  T_imu_cam:", *_yaml_matrix(T_I_C, "  ")]
        else:
            lines += ["  T_cam_imu:", *_yaml_matrix(np.linalg.inv(T_I_C), "  ")]
            if prev is not None:
                lines += ["  T_cn_cnm1:", *_yaml_matrix(np.linalg.inv(T_I_C) @ prev, "  ")]
        prev = T_I_C
        lines += [
            "  camera_model: pinhole",
            f"  distortion_coeffs: {_yaml_list(cam.distortion)}",
            f"  distortion_model: {kalibr_dist}",
            f"  intrinsics: {_yaml_list(cam.intrinsics)}",
            f"  resolution: [{int(cam.resolution[0])}, {int(cam.resolution[1])}]",
            f"  rostopic: {rostopics[i] if rostopics else f'/cam{i}/image_raw'}",
            f"  timeshift_cam_imu: {format_float(timeshift_cam_imu_s)}",
        ]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_kalibr_imu(path: Path | str, calib: ImuCalib, rostopic: str = "/imu0") -> Path:
    """Write an ``ImuCalib`` as Kalibr's ``imu.yaml`` (flat keys, as Kalibr takes as input)."""
    path = Path(path)
    lines = [f"{theirs}: {format_float(getattr(calib, ours))}" for ours, theirs in IMU_NOISE_KEYS]
    lines += [f"update_rate: {format_float(calib.rate_hz)}", f"rostopic: {rostopic}"]
    path.write_text("\n".join(lines) + "\n")
    return path
