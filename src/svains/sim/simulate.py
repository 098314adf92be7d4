"""``simulate(config, out_dir)``: fly the scenario, simulate every sensor, write an ASL data set.

Timestamps start at 0 ns. Every sensor draws from its own RNG stream spawned from
``config.seed``, so switching one sensor off does not change the others' noise.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.datasets.asl_writer import AslWriter
from svains.datasets.completion import write_marker
from svains.datasets.types import (
    CameraCalib,
    FeatureStream,
    GpsCalib,
    GpsStream,
    GroundTruth,
    ImuCalib,
    ImuStream,
    MagCalib,
    MagStream,
    SonarCalib,
    SonarStream,
)
from svains.errors import OutputError
from svains.geometry.camera import RectifiedStereo
from svains.outputs import replace_dir, staging_dir
from svains.sim.config import SimConfig
from svains.sim.sensors import (
    SONAR_R_B_S,
    gps_keep_mask,
    project_landmarks,
    sample_times_ns,
    simulate_gps,
    simulate_imu,
    simulate_mag,
    simulate_sonar,
    sonar_mount,
    stereo_rig,
)
from svains.sim.trajectory import (
    SplineTrajectory,
    rounded_rectangle,
    tum_trajectory,
    village_trajectory,
)
from svains.sim.world import World, build_world

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

# Nominal EuRoC mount (cam0 of the VI-sensor, rounded): camera z along the IMU's z axis.
EUROC_R_B_C = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
EUROC_P_B_C = np.array([-0.0216, -0.0647, 0.0098])

KINEMATICS_HEADER = (
    "timestamp [ns],omega_B_x [rad s^-1],omega_B_y [rad s^-1],omega_B_z [rad s^-1],"
    "alpha_B_x [rad s^-2],alpha_B_y [rad s^-2],alpha_B_z [rad s^-2],a_W_x [m s^-2],"
    "a_W_y [m s^-2],a_W_z [m s^-2],f_B_x [m s^-2],f_B_y [m s^-2],f_B_z [m s^-2]"
)
SONAR_MAX_RANGE = 10.0  # m
LANDMARKS_HEADER = "id,p_W_F_x [m],p_W_F_y [m],p_W_F_z [m]"


def forward_R_B_C(tilt_down_deg: float) -> F64:
    """Camera looking along body +x (body x forward, y left, z up), pitched down by the tilt."""
    th = np.radians(tilt_down_deg)
    # columns: camera x (right) = -y_B, camera y (down) = -z_B, camera z (forward) = +x_B
    level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    # rotating about the camera x axis by -th turns the optical axis downwards
    c, s = np.cos(th), np.sin(th)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    return level @ tilt


@dataclass
class Scene:
    """What a simulation run builds before writing: trajectory, world and stereo rig."""

    config: SimConfig
    trajectory: SplineTrajectory
    world: World
    rig: RectifiedStereo


def build_scene(config: SimConfig) -> Scene:
    """Trajectory, village and rig of ``config`` (validated)."""
    config.validate()
    tc = config.trajectory
    if config.scenario == "village":
        traj = village_trajectory(
            config.duration_s, tuple(config.world.size), config.world.corner_radius,
            tc.altitude, tc.speed, gravity=float(-config.gravity_W[2]), bank=tc.bank,
            vibration_deg=tc.vibration_deg, vibration_hz=tc.vibration_hz,
            knot_dt_s=tc.knot_dt_s, seed=config.seed, stops=tc.stops,
            stop_ramp_s=tc.stop_ramp_s,
        )  # fmt: skip
        R_B_C = forward_R_B_C(config.camera.tilt_down_deg)
        p_B_C = np.asarray(config.camera.p_B_C, float)
    else:
        traj = tum_trajectory(str(tc.tum_path), config.duration_s, knot_dt_s=tc.knot_dt_s)
        if traj.t_max < config.duration_s:
            log.warning("TUM trajectory shorter than %.1f s: duration cut to %.1f s",
                        config.duration_s, traj.t_max)
            config.duration_s = float(np.floor(traj.t_max * 10) / 10)
        R_B_C, p_B_C = EUROC_R_B_C, EUROC_P_B_C
    if config.scenario == "village":
        # the village is laid around the whole lap, whatever part of it is flown
        size = config.world.size
        s = np.arange(0.0, 2 * (size[0] + size[1]), 0.2)
        path_xy = rounded_rectangle(s, tuple(size), config.world.corner_radius)[0]
        ground = 0.0
    else:
        path = traj.evaluate(np.arange(0.0, config.duration_s, 0.1)).p_W_B
        path_xy = path[:, :2]
        # real flights may dip below their frame's z = 0 (EuRoC MH): keep the ground below them
        ground = min(0.0, float(np.floor((path[:, 2].min() - 0.3) * 10.0) / 10.0))
    world = build_world(config.world, path_xy, config.seed, ground_height=ground)
    rig = stereo_rig(config.camera, R_B_C)
    rig = RectifiedStereo(rig.f, rig.cu, rig.cv, rig.baseline, R_B_C, p_B_C, rig.width,
                          rig.height)
    return Scene(config, traj, world, rig)


def _T(R: F64, p: F64) -> F64:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def camera_calibs(
    rig: RectifiedStereo, rate_hz: float, lens: str = "pinhole",
    fisheye_distortion: list[float] | None = None,
) -> tuple[CameraCalib, CameraCalib]:
    """cam0/cam1 calibrations with equal orientation: ideal rectified (zero radial-tangential
    distortion) or, for ``lens="equidistant"``, fisheye with ``fisheye_distortion`` (k1..k4)."""
    intr = np.array([rig.f, rig.f, rig.cu, rig.cv])
    p1 = rig.p_B_C + rig.R_B_C[:, 0] * rig.baseline
    res = (rig.width, rig.height)
    model, dist = "radial-tangential", np.zeros(4)
    if lens == "equidistant":
        model, dist = "equidistant", np.asarray(fisheye_distortion, dtype=float)
    return (
        CameraCalib("cam0", _T(rig.R_B_C, rig.p_B_C), rate_hz, res, intr, model, dist.copy()),
        CameraCalib("cam1", _T(rig.R_B_C, p1), rate_hz, res, intr, model, dist.copy()),
    )


def simulate_features(scene: Scene, t_ns: NDArray[np.int64], rng: np.random.Generator) -> (
    FeatureStream
):
    """True landmark projections with pixel noise, occlusion and field-of-view culling."""
    cfg = scene.config.camera
    truth = scene.trajectory.evaluate(t_ns * 1e-9)
    rows_t, rows_id, rows_l, rows_r = [], [], [], []
    for k, t in enumerate(t_ns):
        R_W_C = truth.R_W_B[k] @ scene.rig.R_B_C
        p_W_C = truth.p_W_B[k] + truth.R_W_B[k] @ scene.rig.p_B_C
        lm = scene.world.landmarks_at(t * 1e-9)
        ids, uv_l, uv_r = project_landmarks(scene.rig, R_W_C, p_W_C, lm, scene.world,
                                            t * 1e-9, cfg.max_depth)
        rows_t.append(np.full(len(ids), t, np.int64))
        rows_id.append(ids)
        rows_l.append(uv_l + cfg.pixel_noise_std * rng.standard_normal(uv_l.shape))
        rows_r.append(uv_r + cfg.pixel_noise_std * rng.standard_normal(uv_r.shape))
    return FeatureStream(
        np.concatenate(rows_t), np.concatenate(rows_id), np.concatenate(rows_l).reshape(-1, 2),
        np.concatenate(rows_r).reshape(-1, 2), cfg.pixel_noise_std,
    )  # fmt: skip


def _images(scene: Scene, t_ns: NDArray[np.int64], right: bool, seed: int) -> Iterator[
    NDArray[np.uint8]
]:
    """Rendered images of one camera, one per timestamp (exposure change and grey noise)."""
    from svains.sim.render import NoiseBank, Renderer, finish_image  # OpenCV only here

    cfg = scene.config.camera
    if cfg.lens == "equidistant":
        from svains.sim.fisheye import FisheyeRenderer

        fisheye = FisheyeRenderer(scene.world, scene.rig, cfg.fisheye_distortion)
        render = fisheye.render
    else:
        renderer = Renderer(scene.world, scene.rig)

        def render(R_W_C: F64, p_W_C: F64, t_s: float) -> NDArray[np.uint8]:
            return renderer.render_with_depth(R_W_C, p_W_C, t_s, full_depth=False)[0]

    rng = np.random.default_rng(seed)
    bank = NoiseBank((scene.rig.height, scene.rig.width), rng)
    truth = scene.trajectory.evaluate(t_ns * 1e-9)
    for k, t in enumerate(t_ns):
        t_s = t * 1e-9
        R_W_C = truth.R_W_B[k] @ scene.rig.R_B_C
        p_W_C = truth.p_W_B[k] + truth.R_W_B[k] @ scene.rig.p_B_C
        if right:
            p_W_C = p_W_C + R_W_C[:, 0] * scene.rig.baseline
        gain = 1.0 + cfg.brightness_amplitude * np.sin(2 * np.pi * t_s / cfg.brightness_period_s)
        img = render(R_W_C, p_W_C, t_s)
        yield finish_image(img, gain, cfg.image_noise_std, rng, bank)


def simulate(config: SimConfig, out_dir: Path | str, overwrite: bool = False) -> Path:
    """Simulate ``config`` and write the data set to ``out_dir`` (its ``mav0/`` inside).

    The data set is written whole or not at all: into a temporary folder inside ``out_dir``,
    closed by the completion marker (``datasets.completion``), then renamed to ``mav0/``.
    Returns the data-set root ``out_dir``. Raises ``ConfigError`` for invalid configurations
    and ``OutputError`` when ``out_dir`` already holds a ``mav0/`` and not ``overwrite``.
    """
    config.validate()
    out = Path(out_dir)
    # Refused before the scene is built: the village alone takes about a second.
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out} exists and is not a folder")
    if (out / "mav0").exists() and not overwrite:
        raise OutputError(f"{out} already holds a data set (mav0/); overwrite it explicitly")
    scene = build_scene(config)
    created = not out.exists()
    try:
        with staging_dir(out) as stage:
            streams = _write_dataset(scene, stage)
            write_marker(stage / "mav0", streams, writer="svains simulate")
            replace_dir(stage / "mav0", out / "mav0")
    except BaseException:
        # interrupted (Ctrl-C, SIGTERM) or failed: a folder made for this data set goes too
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise
    log.info("simulated %s (%.1f s) into %s", scene.config.scenario, scene.config.duration_s, out)
    return out


def _write_dataset(scene: Scene, root: Path) -> list[str]:
    """Simulate every sensor of ``scene`` into ``root/mav0``; return the stream folders."""
    cfg = scene.config
    writer = AslWriter(root)
    seeds = np.random.SeedSequence(cfg.seed).spawn(8)
    rngs = [np.random.default_rng(s) for s in seeds]
    g_W = np.asarray(cfg.gravity_W, float)
    writer.write_body(g_W, comment=f"svains simulator, scenario {cfg.scenario}")

    # IMU and ground truth at the IMU rate
    t_imu = sample_times_ns(cfg.imu.rate_hz, cfg.duration_s)
    truth = scene.trajectory.evaluate(t_imu * 1e-9)
    imu = simulate_imu(truth, g_W, cfg.imu, rngs[0])
    sq = np.sqrt(cfg.imu.rate_hz)  # per-sample std -> continuous density
    writer.write_imu(
        ImuStream(t_imu, imu.gyro_B, imu.accel_B),
        ImuCalib(np.eye(4), cfg.imu.rate_hz, cfg.imu.gyro_noise_std / sq,
                 cfg.imu.gyro_random_walk, cfg.imu.accel_noise_std / sq,
                 cfg.imu.accel_random_walk),
    )  # fmt: skip
    q = truth.q_W_B_wxyz
    # one hemisphere along the flight (w >= 0 everywhere would flip the sign at yaw = 180 deg)
    flips = np.sign(np.einsum("ni,ni->n", q[1:], q[:-1]))
    q = q * np.cumprod(np.concatenate([[1.0], np.where(flips == 0, 1.0, flips)]))[:, None]
    writer.write_groundtruth(GroundTruth(t_imu, truth.p_W_B, q, truth.v_W_B, imu.bg_B, imu.ba_B))
    gt = "state_groundtruth_estimate0"
    kin = np.hstack([truth.omega_B, truth.alpha_B, truth.a_W, truth.specific_force_B(g_W)])
    writer.write_csv_extra(gt, "kinematics.csv", KINEMATICS_HEADER, [t_imu, kin])
    lm_ids = np.arange(len(scene.world.landmarks_W), dtype=np.int64)
    writer.write_csv_extra(gt, "landmarks.csv", LANDMARKS_HEADER,
                           [lm_ids, scene.world.landmarks_W])
    writer.write_text_extra(gt, "scenario.yaml", _scenario_text(scene))

    if cfg.gps.enabled:
        t = sample_times_ns(cfg.gps.rate_hz, cfg.duration_s)
        t = t[gps_keep_mask(t, cfg.gps.outages)]
        p, v = simulate_gps(scene.trajectory.evaluate(t * 1e-9), cfg.gps, rngs[1], t)
        writer.write_gps(GpsStream(t, p, v), GpsCalib(
            np.asarray(cfg.gps.p_B_G, float), cfg.gps.rate_hz, cfg.gps.position_noise_std,
            cfg.gps.velocity_noise_std,
            position_correlation_s=cfg.gps.position_correlation_s))
    if cfg.mag.enabled:
        t = sample_times_ns(cfg.mag.rate_hz, cfg.duration_s)
        m = simulate_mag(scene.trajectory.evaluate(t * 1e-9), cfg.mag.m_W, cfg.mag.noise_std,
                         rngs[2])
        writer.write_mag(MagStream(t, m), MagCalib(np.eye(4), cfg.mag.rate_hz,
                         np.asarray(cfg.mag.m_W, float), cfg.mag.noise_std))
    if cfg.sonar.enabled:
        t = sample_times_ns(cfg.sonar.rate_hz, cfg.duration_s)
        R_B_S = SONAR_R_B_S if cfg.scenario == "village" else sonar_mount(truth.R_W_B)
        r = simulate_sonar(scene.trajectory.evaluate(t * 1e-9), cfg.sonar,
                           scene.world.ground_height, rngs[3], R_B_S)
        ok = r < SONAR_MAX_RANGE  # no echo: tilted away from the ground or out of range
        writer.write_sonar(SonarStream(t[ok], r[ok]), SonarCalib(
            _T(R_B_S, np.asarray(cfg.sonar.p_B_S, float)), cfg.sonar.rate_hz,
            cfg.sonar.noise_std, scene.world.ground_height))
    if cfg.camera.enabled:
        t_cam = sample_times_ns(cfg.camera.rate_hz, cfg.duration_s)  # capture, IMU clock
        features = simulate_features(scene, t_cam, rngs[4])
        # An unsynchronised camera (``camera.timeshift_cam_imu``, t_imu = t_cam + shift): the
        # same captures, stamped on the camera's clock; frames whose stamp falls outside the
        # IMU's span are dropped. The calibration files keep 0 (the offset is unknown).
        shift_ns = round(cfg.camera.timeshift_cam_imu * 1e9)
        t_stamp = t_cam - shift_ns
        inside = (t_stamp >= t_imu[0]) & (t_stamp <= t_imu[-1])
        rows = np.isin(features.t_ns, t_cam[inside])
        writer.write_features(FeatureStream(
            features.t_ns[rows] - shift_ns, features.track_id[rows], features.uv_left[rows],
            features.uv_right[rows], features.pixel_noise_std))  # fmt: skip
        cal0, cal1 = camera_calibs(scene.rig, cfg.camera.rate_hz, cfg.camera.lens,
                                   cfg.camera.fisheye_distortion)
        render = cfg.camera.render_images
        t_img = t_cam[inside] if render else t_cam[:0]
        seed = int(rngs[5].integers(2**31))
        # the two cameras render and encode in two threads (OpenCV and numpy release the GIL);
        # each has its own renderer and noise stream, so the result does not depend on timing
        with ThreadPoolExecutor(max_workers=2) as pool:
            jobs = [
                pool.submit(writer.write_camera, cal, t_img - shift_ns,
                            _images(scene, t_img, right, seed + right) if render else [])
                for cal, right in ((cal0, False), (cal1, True))
            ]
            for job in jobs:
                job.result()
    return sorted(p.name for p in writer.mav0.iterdir() if p.is_dir())


def _scenario_text(scene: Scene) -> str:
    """The configuration plus facts about the generated world (YAML)."""
    import yaml

    world = scene.world
    moving = np.nonzero(world.landmark_moving)[0]
    facts = {
        "world": {
            "n_solids": len(world.solids),
            "n_faces": len(world.faces),
            "n_landmarks": len(world.landmarks_W),
            "ground_height": world.ground_height,
            "moving_landmark_ids": [int(moving.min()), int(moving.max())] if len(moving) else [],
            "moving_direction_W": world.moving_direction_W.tolist(),
            "note": "landmarks.csv holds positions at t = 0; moving landmarks are displaced by "
                    "moving_amplitude * asin(0.99 sin(2 pi t / moving_period_s)) / asin(0.99)"
                    " * moving_direction_W (a near-constant-speed walk)",
        },
        "camera_R_B_C": scene.rig.R_B_C.tolist(),
        "camera_p_B_C": np.asarray(scene.rig.p_B_C).tolist(),
        "noise_note": "sensor noise stds in this file are discrete per-sample values; imu0 "
                      "sensor.yaml densities = std / sqrt(rate_hz)",
    }
    return scene.config.to_yaml() + yaml.safe_dump({"generated": facts}, sort_keys=False)
