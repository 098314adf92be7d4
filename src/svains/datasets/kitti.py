"""Read the KITTI odometry layout: ``image_0/``, ``image_1/``, ``calib.txt``, ``times.txt``,
optional ``poses.txt``.

KITTI images are already rectified, so both cameras get zero distortion and the body frame B is
the left camera (``T_B_C0`` = identity, ``T_B_C1`` = translation ``(b, 0, 0)``). The world frame
is KITTI's: the left camera frame at the first pose (x right, y down, z forward), so gravity is
taken as ``(0, +9.81, 0)`` (approximate: it assumes the first frame is level).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from svains.datasets._image_io import read_grey
from svains.datasets._textio import read_text
from svains.datasets.types import CameraCalib, Dataset, GroundTruth, ImageStream
from svains.datasets.validate import MIN_BASELINE_M, check_camera_calib, image_size
from svains.errors import CalibrationError, DatasetError
from svains.geometry.rotation import rotmat_to_quat

log = logging.getLogger(__name__)

KITTI_GRAVITY_W = (0.0, 9.81, 0.0)


def is_kitti(path: Path) -> bool:
    """A KITTI odometry sequence folder (``calib.txt`` or ``image_0/`` present)."""
    return (path / "calib.txt").is_file() or (path / "image_0").is_dir()


def read_projections(path: Path) -> dict[str, np.ndarray]:
    """``calib.txt`` rows ``NAME: 12 numbers`` as 3x4 matrices."""
    if not path.is_file():
        raise DatasetError(f"missing file: {path}")
    out: dict[str, np.ndarray] = {}
    for k, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        key, _, rest = line.partition(":")
        try:
            vals = np.array([float(v) for v in rest.split()])
        except ValueError:
            raise DatasetError(f"{path}:{k}: malformed calibration row {line[:60]!r}") from None
        if vals.size == 12:
            out[key.strip()] = vals.reshape(3, 4)
    for key in ("P0", "P1"):
        if key not in out:
            raise CalibrationError(f"{path}: missing projection matrix '{key}:' (12 numbers)")
    return out


def _read_table(path: Path, n_cols: int) -> tuple[np.ndarray, list[int]]:
    rows: list[list[float]] = []
    lines: list[int] = []
    for k, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split()
        if len(fields) != n_cols:
            raise DatasetError(
                f"{path}:{k}: malformed row, expected {n_cols} fields, got {len(fields)}"
            )
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise DatasetError(f"{path}:{k}: malformed number in {line[:60]!r}") from None
        lines.append(k)
    a = np.array(rows, dtype=float).reshape(len(rows), n_cols)
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise DatasetError(f"{path}:{lines[int(bad[0])]}: NaN or infinite value")
    return a, lines


def read_kitti(root: Path) -> Dataset:
    """Read a KITTI odometry sequence folder; ``groundtruth`` holds LEFT-CAMERA poses (B = C0).

    Velocities are central finite differences of the positions; biases are zero (no IMU).
    """
    P = read_projections(root / "calib.txt")
    P0, P1 = P["P0"], P["P1"]
    if not (P0[0, 0] > 0 and P1[0, 0] > 0):
        raise CalibrationError(f"{root / 'calib.txt'}: non-positive focal length")
    if not -P1[0, 3] / P1[0, 0] >= MIN_BASELINE_M:
        raise CalibrationError(
            f"{root / 'calib.txt'}: P1 gives a baseline of {-P1[0, 3] / P1[0, 0]:.4g} m "
            f"(-P1[0,3]/P1[0,0]), expected > {MIN_BASELINE_M:g} m"
        )
    times_path = root / "times.txt"
    if not times_path.is_file():
        raise DatasetError(f"missing file: {times_path}")
    t_s, lines = _read_table(times_path, 1)
    t_ns = np.round(t_s[:, 0] * 1e9).astype(np.int64)
    d = np.diff(t_ns)
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0]) + 1
        raise DatasetError(
            f"{times_path}:{lines[i]}: non-increasing timestamp {t_s[i, 0]} after {t_s[i - 1, 0]}"
        )
    rate = float(1e9 / np.median(d)) if d.size else 0.0
    n = t_ns.size
    ds = Dataset(root=root, name=root.name, gravity_W=np.array(KITTI_GRAVITY_W))
    baseline = -P1[0, 3] / P1[0, 0]
    missing: dict[str, int] = {}
    for folder, attr, cam in (("image_0", "left", "cam0"), ("image_1", "right", "cam1")):
        d_img = root / folder
        if not d_img.is_dir():
            if folder == "image_0":
                raise DatasetError(f"missing folder: {d_img}")
            continue
        paths = [d_img / f"{i:06d}.png" for i in range(n)]
        keep = np.array([p.is_file() for p in paths], dtype=bool)
        if not keep.any():
            raise DatasetError(f"{d_img}: none of the {n} images listed by times.txt exist")
        if (~keep).any():
            missing[cam] = int((~keep).sum())
        kept = tuple(p for p, k in zip(paths, keep, strict=True) if k)
        setattr(ds, attr, ImageStream(t_ns=t_ns[keep], paths=kept, loader=read_grey))
        Pc = P0 if cam == "cam0" else P1
        T_B_C = np.eye(4)
        if cam == "cam1":
            T_B_C[0, 3] = baseline
        setattr(
            ds,
            cam,
            CameraCalib(
                name=cam,
                T_B_C=T_B_C,
                rate_hz=rate,
                resolution=image_size(kept[0]),
                intrinsics=np.array([Pc[0, 0], Pc[1, 1], Pc[0, 2], Pc[1, 2]]),
                distortion_model="radial-tangential",
                distortion=np.zeros(4),
            ),
        )
    for cam in (ds.cam0, ds.cam1):
        if cam is not None:
            check_camera_calib(cam, root / "calib.txt")
    ds.missing_images = missing
    if missing:
        log.warning(
            "%s: %d image(s) listed by times.txt but absent on disk, skipped (%s)",
            root, sum(missing.values()), ", ".join(f"{k}: {v}" for k, v in missing.items()),
        )  # fmt: skip
    poses = root / "poses.txt"
    if poses.is_file():
        a, _ = _read_table(poses, 12)
        if a.shape[0] != n:
            raise DatasetError(f"{poses}: {a.shape[0]} poses for {n} timestamps in times.txt")
        T = a.reshape(n, 3, 4)
        p = T[:, :, 3].copy()
        dt_s = (t_ns - t_ns[0]) * 1e-9
        v = np.gradient(p, dt_s, axis=0) if n > 1 else np.zeros_like(p)
        ds.groundtruth = GroundTruth(
            t_ns=t_ns, p_W_B=p, q_W_B_wxyz=rotmat_to_quat(T[:, :, :3]), v_W_B=v,
            bg_B=np.zeros((n, 3)), ba_B=np.zeros((n, 3)),
        )  # fmt: skip
    return ds
