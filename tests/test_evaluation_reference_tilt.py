"""A ground-truth frame tilted from gravity (EuRoC's Vicon frame: 0.24 deg) is detected from the
IMU and the ground truth, and levelled before a posyaw alignment; a level one is left alone."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from _ins_truth import make_dataset
from svains.datasets.types import Dataset, GroundTruth, ImuStream
from svains.evaluation.accuracy import accuracy_report
from svains.evaluation.alignment import rotation_about_axis
from svains.evaluation.reference_tilt import estimate_reference_gravity, leveling_rotation
from svains.evaluation.run import reference_leveling, run_accuracy
from svains.geometry.rotation import quat_box_plus, quat_multiply, rotmat_to_quat
from svains.navigation.outputs import RunResult
from svains.replay.groundtruth import interpolate_groundtruth

TILT_AXIS = np.array([0.6, 0.8, 0.0])  # horizontal
TILT_DEG = 0.3


def _rotated(gt: GroundTruth, R: np.ndarray) -> GroundTruth:
    """The same ground truth expressed in a frame rotated by ``R`` (``p' = R p``)."""
    q = quat_multiply(rotmat_to_quat(R)[None, :], gt.q_W_B_wxyz)
    return replace(gt, p_W_B=gt.p_W_B @ R.T, v_W_B=gt.v_W_B @ R.T, q_W_B_wxyz=q)


def _every(gt: GroundTruth, k: int) -> GroundTruth:
    """Every k-th ground-truth sample (EuRoC's is at 20 Hz, its IMU at 200 Hz)."""
    return GroundTruth(*(np.asarray(a)[::k] for a in (gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz,
                                                        gt.v_W_B, gt.bg_B, gt.ba_B)))  # fmt: skip


def _datasets() -> tuple[Dataset, Dataset, np.ndarray]:
    """A level data set (analytic flight, noisy biased IMU, 20 Hz ground truth) and the same
    with its reference frame ``Wr`` tilted by ``R_Wr_W`` (returned too)."""
    level = make_dataset(60.0, seed=4)
    level.gps = level.gps_calib = None
    level.groundtruth = _every(level.groundtruth, 5)
    R_Wr_W = rotation_about_axis(TILT_AXIS, np.radians(TILT_DEG))
    tilted = replace(level, groundtruth=_rotated(level.groundtruth, R_Wr_W))
    return level, tilted, R_Wr_W


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def test_tilted_reference_is_detected_and_its_levelling_undoes_it() -> None:
    level, tilted, R_Wr_W = _datasets()
    est = estimate_reference_gravity(tilted)
    assert est is not None and est.significant
    assert est.tilt_deg == pytest.approx(TILT_DEG, abs=0.02)
    assert est.tilt_std_deg < 0.01 and est.span_s > 55.0
    # Gravity in the tilted frame points along R_Wr_W g_W.
    g_dir = R_Wr_W @ level.gravity_W / np.linalg.norm(level.gravity_W)
    assert _angle_deg(leveling_rotation(est.g_Wr, g_dir)) < 0.02
    # The smallest rotation levelling it is the tilt's inverse (the tilt axis is horizontal).
    R_W_Wr = leveling_rotation(est.g_Wr, level.gravity_W)
    assert _angle_deg(R_W_Wr @ R_Wr_W) < 0.02
    # The level data set: ~0, not removed.
    flat = estimate_reference_gravity(level)
    assert flat is not None and flat.tilt_deg < 0.02 and not flat.significant
    assert flat.reason.startswith("level")


def _local_result(ds: Dataset, seed: int) -> RunResult:
    """A consistent 'estimate' at 10 Hz in a gravity-aligned local frame (yawed and shifted
    from the level truth, as after a static start without GPS), with its covariance."""
    rng = np.random.default_rng(seed)
    t_ns = ds.groundtruth.t_ns[::2]
    _, p, v, q = interpolate_groundtruth(ds.groundtruth, t_ns)
    sig = np.array([0.02] * 3 + [0.01] * 3 + [0.002] * 3)  # m, m/s, rad (0.11 deg)
    e = rng.normal(size=(len(t_ns), 9)) * sig
    R0 = rotation_about_axis([0.0, 0.0, 1.0], 1.2)
    t0 = np.array([3.0, -1.0, 0.5])
    x = np.zeros((len(t_ns), 13))
    x[:, 0:3] = (p - e[:, 0:3]) @ R0.T + t0
    x[:, 3:6] = (v - e[:, 3:6]) @ R0.T
    x[:, 6:10] = quat_multiply(rotmat_to_quat(R0)[None], quat_box_plus(q, -e[:, 6:9]))
    P9 = np.tile(np.diag(sig**2), (len(t_ns), 1, 1))
    return RunResult(t_ns, x, np.tile(sig, (len(t_ns), 1)), P9, {"method": "3d"},
                     world_frame="local")  # fmt: skip


def test_posyaw_errors_use_the_levelled_reference() -> None:
    level, tilted, _ = _datasets()
    res = _local_result(level, seed=7)
    truth = run_accuracy(res, level)  # the estimate against its own, level, truth
    assert truth["errors_alignment"] == "posyaw" and truth["reference_tilt_deg"] is None
    got = run_accuracy(res, tilted)
    assert got["reference_tilt_deg"] == pytest.approx(TILT_DEG, abs=0.02)
    assert got["reference_gravity"]["significant"] is True
    # Levelled: the errors and the NEES are the level reference's, within the estimate's error.
    assert got["attitude_rmse_deg"] == pytest.approx(truth["attitude_rmse_deg"], rel=0.02)
    assert got["nees_blocks"]["roll_pitch"] == pytest.approx(2.0, abs=0.3)
    assert got["nees_mean"] == pytest.approx(truth["nees_mean"], rel=0.05)
    # Not levelled, the 0.3 deg tilt (2.6 σ) dominates the roll/pitch NEES.
    raw = accuracy_report(res.t_ns, res.x, res.P9, tilted.groundtruth, errors_alignment="posyaw")
    assert raw["nees_blocks"]["roll_pitch"] > 6.0
    assert raw["nees_blocks"]["yaw"] == pytest.approx(got["nees_blocks"]["yaw"], abs=0.3)
    # ATE (se3, evo) is the reference's as it is: untouched.
    assert got["ate_rmse_m"] == pytest.approx(raw["ate_rmse_m"], rel=1e-12)


def test_tilt_is_left_alone_when_the_run_is_in_the_reference_frame() -> None:
    _, tilted, _ = _datasets()
    res = replace(_local_result(tilted, seed=1), world_frame="groundtruth")
    R, keys = reference_leveling(res, tilted)
    # Estimated and reported, but an unaligned run's world is the reference's: not rotated.
    assert R is None and keys["reference_tilt_deg"] is None
    assert keys["reference_gravity"]["significant"] is True


def test_no_estimate_without_imu_and_implausible_data_are_not_levelled(
    caplog: pytest.LogCaptureFixture,
) -> None:
    _, tilted, _ = _datasets()
    assert estimate_reference_gravity(replace(tilted, imu=None)) is None
    assert reference_leveling(_local_result(tilted, 2), replace(tilted, imu=None)) == (
        None, {"reference_tilt_deg": None, "reference_gravity": None})  # fmt: skip
    imu = tilted.imu
    scaled = replace(tilted, imu=ImuStream(imu.t_ns, imu.gyro_B, 1.05 * imu.accel_B))
    with caplog.at_level(logging.WARNING, logger="svains.evaluation.reference_tilt"):
        est = estimate_reference_gravity(scaled)
    assert est is not None and not est.significant and est.reason.startswith("implausible")
    assert "reference tilt not removed" in caplog.text
