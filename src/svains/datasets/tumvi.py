"""Read the TUM-VI layout: ``mav0/{cam0,cam1,imu0,mocap0}`` plus ``dso/camchain.yaml``.

TUM-VI (Schubert et al., IROS 2018) ships EuRoC-style ``data.csv`` tables; its calibration is a
Kalibr ``dso/camchain.yaml`` (``T_cam_imu``, equidistant distortion) and ``dso/imu_config.yaml``
(noise densities), and its ground truth ``mav0/mocap0/data.csv`` holds poses only
(``t, p xyz, q wxyz``), taken as the body (IMU) pose: velocity by central differences, biases
zero. A stream folder that has its own ``sensor.yaml`` is read as in the ASL layout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from svains.datasets.asl_reader import (
    _table,
    find_mav0,
    read_camera,
    read_image_list,
    read_imu,
)
from svains.datasets.kalibr import apply_kalibr
from svains.datasets.trajectory import groundtruth_from_poses
from svains.datasets.types import DEFAULT_GRAVITY_W, Dataset, ImuStream
from svains.errors import DatasetError

CAMCHAIN = Path("dso") / "camchain.yaml"
IMU_CONFIG = Path("dso") / "imu_config.yaml"


def _mav0_and_root(path: Path) -> tuple[Path, Path] | None:
    mav0 = find_mav0(path)
    return None if mav0 is None else (mav0, mav0.parent if mav0.name == "mav0" else mav0)


def is_tumvi(path: Path) -> bool:
    """A TUM-VI sequence folder (root or ``mav0``): ``mocap0`` or ``dso/camchain.yaml``."""
    found = _mav0_and_root(path)
    return found is not None and ((found[0] / "mocap0").is_dir() or (found[1] / CAMCHAIN).is_file())


def read_tumvi(path: Path) -> Dataset:
    """Read a TUM-VI sequence; calibration from ``dso/`` unless the folders carry sensor.yaml."""
    found = _mav0_and_root(path)
    if found is None:
        raise DatasetError(f"{path}: not a TUM-VI sequence (no mav0/)")
    mav0, root = found
    ds = Dataset(root=root, name=root.name, gravity_W=np.array(DEFAULT_GRAVITY_W))
    imu = mav0 / "imu0"
    if (imu / "sensor.yaml").is_file():
        ds.imu, ds.imu_calib = read_imu(imu)
    elif imu.is_dir():
        t, a = _table(imu, 7)
        ds.imu = ImuStream(t_ns=t, gyro_B=a[:, 0:3].copy(), accel_B=a[:, 3:6].copy())
    for cam, attr in (("cam0", "left"), ("cam1", "right")):
        folder = mav0 / cam
        if not folder.is_dir():
            continue
        if (folder / "sensor.yaml").is_file():
            stream, calib, n_missing = read_camera(folder)
            setattr(ds, cam, calib)
        else:
            stream, _, n_missing = read_image_list(folder)
        setattr(ds, attr, stream)
        if n_missing:
            ds.missing_images[cam] = n_missing
    mocap = mav0 / "mocap0"
    if mocap.is_dir():
        t, a = _table(mocap, 8)
        ds.groundtruth = groundtruth_from_poses(t, a[:, 0:3], a[:, 3:7])
    camchain = root / CAMCHAIN if (root / CAMCHAIN).is_file() else None
    imu_cfg = root / IMU_CONFIG if (root / IMU_CONFIG).is_file() and ds.imu_calib is None else None
    if camchain is not None and ds.cam0 is not None:
        camchain = None  # the folders' own sensor.yaml files win
    return apply_kalibr(ds, camchain, imu_cfg)
