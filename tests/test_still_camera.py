"""The camera's witness of a rest (``navigation.still_camera``) and the stops' zero-velocity
updates it lets through (``zupt.after_start``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from svains.frontend.types import StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.navigation.still_camera import StillCamera

RIG = RectifiedStereo(400.0, 320.0, 240.0, 0.1, np.eye(3), np.zeros(3), 640, 480)


def _tracks(t_s: float, p_C: np.ndarray, rng: np.random.Generator, std_px: float = 0.5,
            order: np.ndarray | None = None) -> StereoTracks:  # fmt: skip
    """Tracks ending at ``t_s`` of the points ``p_C`` (M, 3) m in the camera, noisy pixels."""
    ids = np.arange(len(p_C)) if order is None else order
    uv_l = RIG.project(p_C) + rng.normal(0.0, std_px, (len(p_C), 2))
    uv_r = RIG.project_right(p_C) + rng.normal(0.0, std_px, (len(p_C), 2))
    e = np.zeros((len(p_C), 2))
    return StereoTracks(int((t_s - 0.1) * 1e9), int(t_s * 1e9), ids, e, e, uv_l[ids], uv_r[ids],
                        np.zeros((len(p_C), 3)), np.ones(len(p_C), bool), None)  # fmt: skip


def _scene(rng: np.random.Generator, depth: tuple[float, float], n: int = 60) -> np.ndarray:
    z = rng.uniform(*depth, n)
    return np.column_stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.4, 0.4, n) * z, z])


def test_a_still_camera_bounds_its_speed_and_a_moving_one_does_not() -> None:
    rng = np.random.default_rng(0)
    p = _scene(rng, (2.0, 8.0))
    still, moving, creeping = (StillCamera(RIG, 0.5, 0.5) for _ in range(3))
    for k in range(1, 9):  # 10 Hz, 0.5 px of noise
        t = 0.1 * k
        still.observe(_tracks(t, p, rng))
        # 0.3 m/s sideways and forward, ids in another order
        moving.observe(_tracks(t, p - np.array([0.3, 0.0, 0.3]) * t, rng,
                               order=np.arange(len(p))[::-1].copy()))  # fmt: skip
        creeping.observe(_tracks(t, p - np.array([0.0, 0.0, 0.04]) * t, rng))
        if k < 6:  # under 0.5 s of frames: cannot tell
            assert still.speed_bound(int(t * 1e9)) is None
    bound = still.speed_bound(int(0.8e9))
    assert bound is not None and bound < 0.05
    fast = moving.speed_bound(int(0.8e9))
    assert fast is not None and fast > 0.3
    # 4 cm/s forward (a review: a median pixel motion under 1.5 px called 0.05-0.2 m/s still)
    slow = creeping.speed_bound(int(0.8e9))
    assert slow is not None and slow > 0.04
    assert still.speed_bound(int(1.4e9)) is None  # the latest frame 0.6 s old
    assert len(still._frames) <= 7  # nothing older than the span is kept


def test_things_moving_with_the_camera_and_a_pull_away_are_no_rest() -> None:
    """A review: features on a hood or a car ahead (moving with the camera), which RANSAC had
    flagged, read a camera driving at 0.5 m/s as still; the span's average lagged a pull-away
    (0.05 m/s fused as rest)."""
    rng = np.random.default_rng(3)
    scene, riders = _scene(rng, (10.0, 40.0), n=50), _scene(rng, (2.0, 3.0), n=12)
    flagged, kept = StillCamera(RIG, 0.5, 0.5), StillCamera(RIG, 0.5, 0.5)
    for k in range(1, 8):
        t = 0.1 * k
        tr = _tracks(t, np.vstack([scene - np.array([0.0, 0.0, 0.5]) * t, riders]), rng)
        inlier = np.arange(62) < 50
        flagged.observe(dataclasses.replace(tr, inlier=inlier))
        kept.observe(tr)  # the riders kept as inliers: the fit's misfit tells
    fast = flagged.speed_bound(int(0.7e9))
    assert fast is not None and fast > 0.3
    assert kept.speed_bound(int(0.7e9)) is None
    # at rest for 0.6 s, then 0.15 m/s forward over the last frame pair
    cam = StillCamera(RIG, 0.5, 0.5)
    p = _scene(rng, (2.0, 8.0))
    for k in range(1, 8):
        cam.observe(_tracks(0.1 * k, p, rng))
    assert cam.speed_bound(int(0.7e9)) < 0.05  # type: ignore[operator]
    cam.observe(_tracks(0.8, p - np.array([0.0, 0.0, 0.015]), rng))
    assert cam.speed_bound(int(0.8e9)) == np.inf


def test_the_start_rest_ends_when_the_camera_sees_a_creep_three_frames_running() -> None:
    """``start_rest_std``: a resting camera over 200 frames never ends the start's rest (its
    span's chi-square stays under 1e-4's); one creeping at 4 cm/s ends it within a second,
    after three frames running, a frame counted once however often it is asked."""
    rng = np.random.default_rng(4)
    p = _scene(rng, (2.0, 8.0))
    still, creep = StillCamera(RIG, 0.5, 0.5), StillCamera(RIG, 0.5, 0.5)
    said = []
    for k in range(1, 201):
        t = 0.1 * k
        still.observe(_tracks(t, p, rng))
        said.append(still.start_rest_std(int(t * 1e9), 0.002))
    assert np.inf not in said
    loosened = [s for s in said if s is not None]
    assert len(loosened) <= 6 and all(0.002 < s < 0.05 for s in loosened)  # ~1 % at 0.99
    verdicts = []
    for k in range(1, 21):
        t = 0.1 * k
        creep.observe(_tracks(t, p - np.array([0.0, 0.0, 0.04]) * max(t - 0.5, 0.0), rng))
        for _ in range(3):  # asked three times per frame
            verdicts.append(creep.start_rest_std(int(t * 1e9), 0.002))
    seen = [i // 3 for i, v in enumerate(verdicts) if v is not None]
    ended = [i // 3 for i, v in enumerate(verdicts) if v == np.inf]
    assert ended and ended[0] <= 12, ended  # within 0.7 s of setting off
    assert ended[0] >= seen[0] + 2  # three frames running, not three asks of one


def test_a_far_scene_cannot_bound_the_speed_tightly() -> None:
    """Features 40-80 m away move 0.5 px in 0.5 s at 0.1 m/s: the bound says so."""
    rng = np.random.default_rng(1)
    p = _scene(rng, (40.0, 80.0))
    cam = StillCamera(RIG, 0.5, 0.5)
    for k in range(1, 8):
        cam.observe(_tracks(0.1 * k, p, rng))
    bound = cam.speed_bound(int(0.7e9))
    assert bound is not None and bound > 0.1


def test_too_few_common_features_or_a_frame_without_tracks_cannot_tell() -> None:
    rng = np.random.default_rng(2)
    p = _scene(rng, (2.0, 8.0), n=30)
    cam = StillCamera(RIG, 0.5, 0.5)
    cam.observe(_tracks(0.1, p, rng))
    tr = _tracks(0.7, p, rng)
    cam.observe(dataclasses.replace(tr, track_id=tr.track_id + 21))  # 9 features at both ends
    assert cam.speed_bound(int(0.7e9)) is None
    cam.observe(dataclasses.replace(_tracks(1.3, p, rng), track_id=tr.track_id + 21))
    assert cam.speed_bound(int(1.3e9)) is not None
    cam.observe(None)  # the span broken
    assert cam.speed_bound(int(1.3e9)) is None


@pytest.fixture(scope="module")
def robot_with_a_stop(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ground robot (camera forward, 0.5 m up): rest 0-3 s, 0.8 m/s with a gentle turn,
    a stop from 9 to 14 s, 0.8 m/s to 20 s; 10 Hz stereo features, no GPS."""
    from scipy.spatial.transform import Rotation

    from svains.sim import SimConfig, simulate
    from svains.sim.config import ImuConfig

    folder = tmp_path_factory.mktemp("robot")
    dt = 0.005
    t = np.arange(0.0, 20.1 + dt / 2, dt)

    def leg(t0: float, t1: float, ramp: float = 1.5) -> np.ndarray:
        s = np.clip(np.minimum(t - t0, t1 - t) / ramp, 0.0, 1.0)
        return 0.8 * 0.5 * (1.0 - np.cos(np.pi * s))

    speed = leg(3.0, 9.0) + leg(14.0, 20.5)
    yaw = np.cumsum(np.where((t > 5) & (t < 8), 0.2 * np.sin(np.pi * (t - 5) / 3), 0.0)) * dt
    x, y = np.cumsum(speed * np.cos(yaw)) * dt, np.cumsum(speed * np.sin(yaw)) * dt
    base = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])  # EuRoC's IMU axes
    q = Rotation.from_matrix(Rotation.from_euler("z", yaw[:, None]).as_matrix() @ base).as_quat()
    rows = np.column_stack([t, x, y, np.full_like(t, 0.5), q])
    np.savetxt(folder / "robot.tum", rows, fmt="%.6f")
    cfg = SimConfig(scenario="trajectory", duration_s=20.0, seed=3,
                    imu=ImuConfig.preset("adis16448"))  # the paper's IMU fails the rest test
    cfg.trajectory.tum_path = str(folder / "robot.tum")
    cfg.trajectory.vibration_deg = 0.0  # a wheeled robot, not a MAV
    cfg.camera.rate_hz = 10.0
    cfg.camera.render_images = False
    return simulate(cfg, folder / "ds")


def test_a_robots_stop_gets_zero_velocity_updates_and_its_drive_none(
    robot_with_a_stop: Path,
) -> None:
    """By default (``zupt.after_start`` None) a vision method tests every rest: the IMU's rest
    test passed on straight driving at 0.8 m/s and the filter met hundreds of "v = 0" updates
    there (a probe's robot: 323 refused, velocity NEES 5.69); the camera's witness leaves the
    drive out and the stop in. ``ins`` keeps the start's rest alone."""
    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.config_io import from_dict

    ds = load_dataset(robot_with_a_stop)
    config = from_dict({"method": "ins", "use_gps": False, "use_sonar": False})
    result = run_method(ds, options=config)
    t0 = int(result.t_ns[0])
    t_s = np.array([u.t_ns - t0 for u in result.update_log if u.sensor == "zupt"]) * 1e-9
    assert t_s.size > 0 and t_s.max() < 3.5  # the start's rest only
    assert "zupt_camera_not_still" not in result.report
    config = from_dict({"method": "3d", "use_gps": False, "use_sonar": False})
    result = run_method(ds, options=config)
    t0 = int(result.t_ns[0])
    zupt = [(u.t_ns - t0, u.stats.accepted) for u in result.update_log if u.sensor == "zupt"]
    t_s = np.array([z[0] for z in zupt]) * 1e-9
    accepted = np.array([z[1] for z in zupt])
    driving = ((t_s > 5.0) & (t_s < 7.5)) | ((t_s > 16.0) & (t_s < 19.5))
    assert not driving.any(), t_s[driving]  # not even tried
    stopped = (t_s > 9.8) & (t_s < 13.5)
    assert accepted[stopped].sum() >= 30
    assert result.report["zupt_camera_not_still"] > 50
    speed = np.linalg.norm(result.x[:, 3:6], axis=1)
    at_stop = ((result.t_ns - t0) * 1e-9 > 10.0) & ((result.t_ns - t0) * 1e-9 < 13.5)
    assert speed[at_stop].max() < 0.01
    # nor at the pull-away, where the camera's verdict is a frame old (a probe: 0.05 m/s
    # fused as rest 0.2 s into one): the IMU says whether it set off since that frame
    gt = ds.groundtruth
    true_speed = np.linalg.norm([np.interp(t0 + t_s * 1e9, gt.t_ns, gt.v_W_B[:, i])
                                 for i in range(3)], axis=0)  # fmt: skip
    assert not ((t_s > 4.0) & (true_speed > 0.01)).any(), t_s[(t_s > 4.0) & (true_speed > 0.01)]


def test_stops_for_ins_are_warned(caplog: pytest.LogCaptureFixture) -> None:
    """``ins`` has no camera to witness a rest: 8 village flights with stops went 6.6 -> 12.4 m
    with it (``bench/specs/stops_village.yaml``)."""
    from svains import Navigator, RunConfig
    from svains.navigation.options import ZuptOptions
    from svains.sensors.types import Rig

    with caplog.at_level("WARNING", logger="svains.navigation.navigator"):
        Navigator(RunConfig(method="ins", zupt=ZuptOptions(after_start=True)), Rig())
        Navigator(RunConfig(method="ins"), Rig())  # the default: the start's rest alone
    assert [ZuptOptions().after_start_for(m) for m in ("ins", "lc", "tc", "3d")] == [
        False, True, True, True]
    assert not ZuptOptions(after_start=False).after_start_for("3d")
    assert caplog.text.count("zupt.after_start with ins: the IMU's rest test alone") == 1


def test_a_gentle_set_off_ends_the_start_rest_by_the_camera(tmp_path: Path) -> None:
    """A vehicle setting off over 12 s passes the IMU's rest limits for seconds, and the
    start's zeros held it at rest while it crept at up to 5 cm/s (velocity NEES 24.6 of 3 over
    30 s); the camera ends the start's rest about a second after it sets off."""
    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.config_io import from_dict
    from svains.sim import SimConfig, simulate
    from svains.sim.config import ImuConfig

    cfg = SimConfig(duration_s=12.0, seed=2, imu=ImuConfig.preset("adis16448"))
    cfg.trajectory.stops = [[0.0, 2.0]]
    cfg.trajectory.stop_ramp_s = 12.0
    cfg.camera.rate_hz = 10.0
    cfg.camera.render_images = False
    ds = load_dataset(simulate(cfg, tmp_path / "creep"))
    runs = {}
    for start_camera in (True, False):
        config = from_dict({"method": "3d", "use_gps": False, "use_mag": False,
                            "zupt": {"start_camera": start_camera}})  # fmt: skip
        runs[start_camera] = run_method(ds, options=config).report
    ended = runs[True]["zupt_start_camera"]["ended_s"]
    assert ended is not None and 2.5 < ended < 4.0, ended
    v_on, v_off = (runs[k]["nees_blocks"]["velocity"] for k in (True, False))
    assert v_off > 15.0 and v_on < 0.5 * v_off, (v_on, v_off)
    assert "zupt_start_camera" not in runs[False]


def test_a_start_in_motion_reports_no_start_camera(tmp_path: Path) -> None:
    """``zupt_start_camera`` says what the camera did to a start's rest: a start in flight has
    none, and the key read as if one had been checked (a review)."""
    from svains.datasets import load_dataset
    from svains.evaluation.run import run_method
    from svains.navigation.config_io import from_dict
    from svains.sim import SimConfig, simulate

    cfg = SimConfig(duration_s=4.0, seed=1)
    cfg.camera.render_images = False
    ds = load_dataset(simulate(cfg, tmp_path / "flight"))
    config = from_dict({"method": "3d", "use_gps": False, "init": {"mode": "groundtruth"}})
    report = run_method(ds, options=config).report
    assert "zupt_camera_not_still" in report  # the stops' witness is there
    assert "zupt_start_camera" not in report
