"""Kalibr files and bags written from the EuRoC micro set (shared by the bag/Kalibr tests)."""

from __future__ import annotations

from pathlib import Path

from svains.datasets.kalibr import write_camchain, write_kalibr_imu
from svains.datasets.types import Dataset


def write_euroc_kalibr(ds: Dataset, folder: Path) -> tuple[Path, Path]:
    """(camchain-imucam.yaml, imu.yaml) holding ``ds``'s own sensor.yaml calibration."""
    assert ds.cam0 is not None and ds.cam1 is not None and ds.imu_calib is not None
    folder.mkdir(parents=True, exist_ok=True)
    chain = write_camchain(folder / "camchain-imucam.yaml", [ds.cam0, ds.cam1],
                           T_B_I=ds.imu_calib.T_B_S)  # fmt: skip
    return chain, write_kalibr_imu(folder / "imu.yaml", ds.imu_calib)
