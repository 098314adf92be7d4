"""TUM-VI layout: ``mav0`` without sensor.yaml files, ``mocap0`` pose-only ground truth and the
calibration in ``dso/camchain.yaml`` + ``dso/imu_config.yaml`` (a fixture built from EuRoC)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _kalibr_files import write_euroc_kalibr
from svains.datasets import load_dataset
from svains.datasets.tumvi import is_tumvi
from svains.errors import DatasetError


def _tumvi_from_euroc(euroc_micro: Path, root: Path, n_imu: int = 400) -> Path:
    src = euroc_micro / "mav0"
    mav0 = root / "mav0"
    for cam in ("cam0", "cam1"):
        (mav0 / cam).mkdir(parents=True)
        (mav0 / cam / "data.csv").write_text((src / cam / "data.csv").read_text())
        (mav0 / cam / "data").symlink_to(src / cam / "data")
    (mav0 / "imu0").mkdir()
    lines = (src / "imu0" / "data.csv").read_text().splitlines()
    (mav0 / "imu0" / "data.csv").write_text("\n".join(lines[: n_imu + 1]) + "\n")
    (mav0 / "mocap0").mkdir()
    gt = (src / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()
    mocap = ["#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
             "q_RS_y [],q_RS_z []"] + [",".join(r.split(",")[:8]) for r in gt[1:60]]  # fmt: skip
    (mav0 / "mocap0" / "data.csv").write_text("\n".join(mocap) + "\n")
    return root


def test_tumvi_reads_like_the_euroc_folder(euroc_micro: Path, tmp_path: Path) -> None:
    euroc = load_dataset(euroc_micro)
    root = _tumvi_from_euroc(euroc_micro, tmp_path / "dataset-room1_512_16")
    chain, imu = write_euroc_kalibr(euroc, root / "dso")
    chain.rename(root / "dso" / "camchain.yaml")
    imu.rename(root / "dso" / "imu_config.yaml")
    assert is_tumvi(root) and is_tumvi(root / "mav0") and not is_tumvi(euroc_micro)
    ds = load_dataset(root)
    assert ds.name == "dataset-room1_512_16"
    np.testing.assert_array_equal(ds.imu.gyro_B, euroc.imu.gyro_B[:400])
    np.testing.assert_array_equal(ds.left.t_ns, euroc.left.t_ns)
    np.testing.assert_array_equal(ds.right.t_ns, euroc.right.t_ns)
    assert ds.missing_images == euroc.missing_images == {"cam1": 4}
    for ours, theirs in ((ds.cam0, euroc.cam0), (ds.cam1, euroc.cam1)):
        np.testing.assert_allclose(ours.T_B_C, theirs.T_B_C, atol=1e-12)
        np.testing.assert_array_equal(ours.intrinsics, theirs.intrinsics)
        assert ours.rate_hz == pytest.approx(20.0)
    assert ds.imu_calib.accel_noise_density == euroc.imu_calib.accel_noise_density
    gt, ref = ds.groundtruth, euroc.groundtruth
    np.testing.assert_array_equal(gt.t_ns, ref.t_ns[:59])
    np.testing.assert_array_equal(gt.p_W_B, ref.p_W_B[:59])
    # Pose-only: velocity from differences of 20 Hz positions, against EuRoC's estimated one.
    np.testing.assert_allclose(gt.v_W_B, ref.v_W_B[:59], atol=0.03)
    assert not gt.bg_B.any() and not gt.ba_B.any()


def test_tumvi_without_calibration_has_no_cameras_and_bad_mocap_names_its_line(
    euroc_micro: Path, tmp_path: Path
) -> None:
    root = _tumvi_from_euroc(euroc_micro, tmp_path / "seq", n_imu=10)
    ds = load_dataset(root)
    assert ds.cam0 is None and ds.imu_calib is None and len(ds.left) == 95
    path = root / "mav0" / "mocap0" / "data.csv"
    lines = path.read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"mocap0/data\.csv:4: malformed row, expected 8 fields"):
        load_dataset(root)
