"""``init.mode: vision`` for a recording: stereo odometry over the first seconds (the ``vo``
method's chain) against the IMU (``navigation.vision_start``), as the filter's given start."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from svains.datasets.types import Dataset
from svains.errors import InitialisationError
from svains.geometry.rotation import quat_to_rotmat
from svains.models.state import BIASED, PAPER
from svains.navigation.init import InitialState, from_vision_fit
from svains.navigation.options import RunConfig
from svains.navigation.vision_start import fit_vision_inertial, state_at

log = logging.getLogger(__name__)


def vision_start(ds: Dataset, config: RunConfig) -> InitialState:
    """The initial state from the first ``init.vision_window_s`` of stereo frames (from
    ``replay.start_s`` on) and the IMU, at the first IMU sample at or after the first frame.
    ``InitialisationError`` when the window gives no usable fit."""
    from svains.replay.replay import resolve_config
    from svains.replay.vo import run as run_vo  # the front end: only when this start is asked

    assert ds.imu is not None
    o = config.init
    # ``ins`` leaves the tracks' source unresolved (it has none): the odometry's own choice.
    vo_config = resolve_config(ds, replace(config, method="vo", duration_s=o.vision_window_s,
                                           init=replace(o, mode="static")))  # fmt: skip
    vo = run_vo(ds, vo_config, None)
    breaks = set(vo.report["vo"]["break_t_ns"])
    keep = np.array([int(t) not in breaks for t in vo.t_ns], bool)
    if not keep.any():
        raise InitialisationError(f"{ds.name}: in-flight start from vision: no stereo motion in "
                                  f"the first {o.vision_window_s:g} s")  # fmt: skip
    t_f = vo.t_ns[keep]
    R_V_B = quat_to_rotmat(vo.x[keep, 6:10])
    p_V_B = vo.x[keep, 0:3]
    R_B_S = np.eye(3) if ds.imu_calib is None else ds.imu_calib.T_B_S[:3, :3]
    t_imu = np.asarray(ds.imu.t_ns, np.int64)
    gyro_B, accel_B = ds.imu.gyro_B @ R_B_S.T, ds.imu.accel_B @ R_B_S.T
    g_W = np.asarray(ds.gravity_W, float)
    cal = ds.imu_calib
    fit = fit_vision_inertial(t_f, R_V_B, p_V_B, t_imu, gyro_B, accel_B, g_W,
                              o.vision_max_g_error,
                              0.0 if cal is None else cal.gyro_noise_density, o.gyro_bias_std,
                              0.0 if cal is None else cal.accel_noise_density)  # fmt: skip
    k = int(np.searchsorted(t_imu, fit.t0_ns))
    if k >= len(t_imu):
        raise InitialisationError(f"{ds.name}: no IMU sample after the first stereo frame")
    t_s = int(t_imu[k])
    R_W_B, v_W_B = state_at(fit, R_V_B[0], t_imu, gyro_B, accel_B, t_s)
    layout = BIASED if config.model == "biased" else PAPER
    gps_fused = bool(config.use_gps and ds.gps is not None)
    init = from_vision_fit(fit, t_s, R_W_B, v_W_B, gyro_B[k] - fit.b_g, layout, o, g_W,
                           gps_fused)  # fmt: skip
    log.info("in-flight start from vision: %d frames, gravity fitted %.3f m/s², tilt std %.2f°",
             fit.frames, fit.g_fit_mps2, np.degrees(fit.tilt_std))  # fmt: skip
    return init
