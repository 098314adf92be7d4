"""Plain-data summary of a data set (streams, rates, gaps, missing files, calibration)."""

from __future__ import annotations

from typing import Any

import numpy as np

from svains.datasets.loader import stereo_pairs, stream_times
from svains.datasets.stereo_images import recorded_stereo_check
from svains.datasets.types import Dataset
from svains.datasets.validate import gps_course_vs_imu_turn, image_file_problem, mag_frame_turn
from svains.errors import SvainsError

STREAM_LABELS = {
    "imu": "imu0",
    "left": "cam0 (left)",
    "right": "cam1 (right)",
    "groundtruth": "ground truth",
    "gps": "gps0",
    "mag": "mag0",
    "sonar": "sonar0",
    "features": "features0 (frames)",
}


def _stream_stats(t_ns: np.ndarray, t0_ns: int) -> dict[str, Any]:
    """Count, median rate (Hz), start offset and span (s), largest gap (s) and where it starts."""
    n = int(t_ns.size)
    out: dict[str, Any] = {"count": n, "rate_hz": None, "start_s": None, "span_s": None,
                           "largest_gap_s": None, "largest_gap_at_s": None}  # fmt: skip
    if n == 0:
        return out
    out["start_s"] = (int(t_ns[0]) - t0_ns) * 1e-9
    out["span_s"] = (int(t_ns[-1]) - int(t_ns[0])) * 1e-9
    if n > 1:
        d = np.diff(t_ns)
        out["rate_hz"] = 1e9 / float(np.median(d))
        k = int(np.argmax(d))
        out["largest_gap_s"] = float(d[k]) * 1e-9
        out["largest_gap_at_s"] = (int(t_ns[k]) - t0_ns) * 1e-9
    return out


def _cameras(ds: Dataset) -> dict[str, Any]:
    cams: dict[str, Any] = {}
    for cal in (ds.cam0, ds.cam1):
        if cal is None:
            continue
        cams[cal.name] = {
            "resolution": list(cal.resolution),
            "intrinsics_fu_fv_cu_cv": cal.intrinsics.tolist(),
            "distortion_model": cal.distortion_model,
            "distortion": cal.distortion.tolist(),
            "p_B_C": cal.T_B_C[:3, 3].tolist(),
            # where the camera looks on the body: its z (optical) and x (right) axes
            "z_C_in_B": cal.T_B_C[:3, 2].tolist(),
            "x_C_in_B": cal.T_B_C[:3, 0].tolist(),
            "timeshift_cam_imu_s": cal.timeshift_cam_imu_s,
            "rate_hz": cal.rate_hz,
        }
    if ds.cam0 is not None and ds.cam1 is not None:
        T_C0_C1 = np.linalg.inv(ds.cam0.T_B_C) @ ds.cam1.T_B_C
        cams["baseline_m"] = float(np.linalg.norm(T_C0_C1[:3, 3]))
        cams["p_C0_C1"] = T_C0_C1[:3, 3].tolist()  # cam1 in cam0's axes: +x for a right camera
        cos = np.clip((np.trace(T_C0_C1[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        cams["relative_rotation_deg"] = float(np.degrees(np.arccos(cos)))
    return cams


def dataset_summary(ds: Dataset) -> dict[str, Any]:
    """JSON-ready summary: per-stream statistics (times relative to the earliest sample),
    missing image counts and calibration."""
    times = stream_times(ds)
    t0 = min((int(t[0]) for t in times.values() if t.size), default=0)
    streams = {name: {"label": STREAM_LABELS[name], **_stream_stats(t, t0)}
               for name, t in times.items()}  # fmt: skip
    calib: dict[str, Any] = {"gravity_W": ds.gravity_W.tolist(), "cameras": _cameras(ds)}
    if ds.imu_calib is not None:
        c = ds.imu_calib
        calib["imu"] = {
            "rate_hz": c.rate_hz,
            "gyro_noise_density": c.gyro_noise_density,
            "gyro_random_walk": c.gyro_random_walk,
            "accel_noise_density": c.accel_noise_density,
            "accel_random_walk": c.accel_random_walk,
            "T_B_S_is_identity": bool(np.allclose(c.T_B_S, np.eye(4))),
        }
    if ds.gps_calib is not None:
        calib["gps"] = {"p_B_G": ds.gps_calib.p_B_G.tolist(),
                        "position_noise_std": ds.gps_calib.position_noise_std,
                        "velocity_noise_std": ds.gps_calib.velocity_noise_std,
                        "timeshift_gps_imu_s": ds.gps_calib.timeshift_gps_imu_s,
                        "position_correlation_s": ds.gps_calib.position_correlation_s,
                        "fixes_with_velocity": None if ds.gps is None
                        else bool(ds.gps.has_velocity.all())}  # fmt: skip
    if ds.mag_calib is not None:
        calib["mag"] = {"m_W": ds.mag_calib.m_W.tolist(), "noise_std": ds.mag_calib.noise_std}
    if ds.sonar_calib is not None:
        calib["sonar"] = {"noise_std": ds.sonar_calib.noise_std,
                          "ground_height": ds.sonar_calib.ground_height}  # fmt: skip
    if ds.features is not None:
        calib["features"] = {"pixel_noise_std": ds.features.pixel_noise_std,
                             "observations": int(ds.features.t_ns.size),
                             "tracks": int(np.unique(ds.features.track_id).size)}  # fmt: skip
    return {
        "root": str(ds.root),
        "name": ds.name,
        "streams": streams,
        "missing_images": dict(ds.missing_images),
        "unreadable_images": _unreadable_images(ds),
        "stereo_pairs": _stereo_pairs(ds),
        "calibration": calib,
        "checks": _checks(ds),
    }


def _stereo_pairs(ds: Dataset) -> dict[str, Any] | None:
    """Frames the two cameras share (``loader.stereo_pairs``) and those of each without a
    partner (a camera that stopped early, dropped frames); None without two cameras."""
    if ds.left is None or ds.right is None:
        return None
    t, il, ir = stereo_pairs(ds)
    return {"pairs": int(t.size), "cam0_unpaired": len(ds.left) - int(np.unique(il).size),
            "cam1_unpaired": len(ds.right) - int(np.unique(ir).size)}  # fmt: skip


def _unreadable_images(ds: Dataset) -> dict[str, Any]:
    """Per camera stream, the images whose bytes say they cannot be decoded
    (``validate.image_file_problem``: an end chunk missing, an empty file): their count and the
    first with its reason. ``run`` drops such frames with a warning."""
    out: dict[str, Any] = {}
    for name, stream in (("cam0", ds.left), ("cam1", ds.right)):
        if stream is None:
            continue
        bad = [(p, why) for p in stream.paths if (why := image_file_problem(p)) is not None]
        if bad:
            out[name] = {"count": len(bad), "first": str(bad[0][0]), "reason": bad[0][1]}
    return out


def _checks(ds: Dataset) -> dict[str, Any]:
    """The figures the load's unit and frame checks judged (``validate.vet_streams``), so a
    user sees how far from refusal a recording sits."""
    out: dict[str, Any] = {}
    if ds.imu is not None and len(ds.imu.t_ns):
        out["accel_median_mps2"] = float(np.median(np.linalg.norm(ds.imu.accel_B, axis=1)))
        out["gravity_mps2"] = float(np.linalg.norm(ds.gravity_W))
    if ds.imu is not None and ds.gps is not None:
        got = gps_course_vs_imu_turn(ds.imu.t_ns, ds.imu.gyro_B, ds.imu.accel_B, ds.gps.t_ns,
                                     ds.gps.velocity_or_differenced(),
                                     np.asarray(ds.gravity_W, float))  # fmt: skip
        if got is not None:
            cosine, n, turn_deg, ratio = got
            out["gps_course_vs_gyro"] = {"cosine": cosine, "turns": n, "gyro_turn_deg": turn_deg,
                                         "course_per_gyro_turn": ratio}  # fmt: skip
    turn = mag_frame_turn(ds)
    if turn is not None:
        out["mag_turn_vs_gyro"] = {"cosine": turn[0], "turns": turn[1], "gyro_turn_deg": turn[2]}
    try:
        stereo = recorded_stereo_check(ds)
    except SvainsError as exc:  # what a run refuses with, said here too (was hidden)
        out["stereo_pair"] = {"refused": str(exc)}
        stereo = None
    if stereo is not None:
        out["stereo_pair"] = {**stereo.summary(), "problem": stereo.problem()}
    return out
