"""``svains.Navigator`` fed by hand, measurement by measurement, from the recordings' files (no
``Dataset`` object): the same trajectories as ``svains run`` (its replay, recorded in
``tests/golden``), for ins, lc, tc and 3d on EuRoC micro and a 30 s simulated village."""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _golden_cases import CASES, EUROC_MICRO, Case, case_params, summarise, village_root
from svains import Navigator
from svains.datasets.asl_reader import (
    read_camera_calib,
    read_features,
    read_gps,
    read_groundtruth,
    read_imu,
    read_mag,
    read_sonar,
)
from svains.models.state import BIASED, PAPER
from svains.navigation.init import ImuArrays, InitData, initialise
from svains.navigation.options import InitOptions, RunConfig, VisionOptions
from svains.navigation.vision import tune_for_frames
from svains.navigation.vision_sources import rig_from_calibrations
from svains.replay.replay import _FRAME as FRAME
from svains.replay.replay import _GPS as GPS
from svains.replay.replay import _IMU as IMU
from svains.replay.replay import _MAG as MAG
from svains.replay.replay import _SONAR as SONAR
from svains.replay.replay import feed
from svains.replay.synthetic import room_landmarks, synthesize_features
from svains.sensors.types import Rig
from test_golden import assert_matches_golden


@functools.lru_cache(maxsize=2)
def _files(root: Path, synthetic: bool) -> dict[str, Any]:
    """Streams and calibrations read file by file from an ASL folder."""
    mav0 = root / "mav0"
    imu, imu_cal = read_imu(mav0 / "imu0")
    cam0, cam1 = read_camera_calib(mav0 / "cam0"), read_camera_calib(mav0 / "cam1")
    out: dict[str, Any] = {"imu": imu, "imu_cal": imu_cal, "cam0": cam0, "cam1": cam1,
                           "gt": read_groundtruth(mav0 / "state_groundtruth_estimate0")}
    for name, reader in (("gps", read_gps), ("mag", read_mag), ("sonar", read_sonar)):
        if (mav0 / f"{name}0").is_dir():
            out[name], out[f"{name}_cal"] = reader(mav0 / f"{name}0")
    if synthetic:  # the replay's --synthetic-features 5, from its building blocks
        rng = np.random.default_rng(0)
        gt = out["gt"]
        landmarks = room_landmarks(gt.p_W_B, 4000, rng)
        frames = np.arange(int(gt.t_ns[0]), int(gt.t_ns[-1]) + 1, round(1e9 / 5.0))
        out["features"] = synthesize_features(frames, gt, rig_from_calibrations(cam0, cam1),
                                              landmarks, 0.5, rng)
    elif (mav0 / "features0").is_dir():
        out["features"] = read_features(mav0 / "features0")
    return out


def _events(f: dict[str, Any], vision: bool) -> list[tuple[int, int, tuple]]:
    ev: list[tuple[int, int, tuple]] = []
    imu = f["imu"]
    ev += [(int(t), IMU, (g, a)) for t, g, a in zip(imu.t_ns, imu.gyro_B, imu.accel_B,
                                                      strict=True)]
    if "gps" in f:
        ev += [(int(t), GPS, (p, v)) for t, p, v in zip(f["gps"].t_ns, f["gps"].p_W_G,
                                                        f["gps"].v_W_G, strict=True)]
    if "mag" in f:
        ev += [(int(t), MAG, (m,)) for t, m in zip(f["mag"].t_ns, f["mag"].m_S, strict=True)]
    if "sonar" in f:
        ev += [(int(t), SONAR, (r,)) for t, r in zip(f["sonar"].t_ns, f["sonar"].range_m,
                                                     strict=True)]
    if vision:
        fs = f["features"]
        times, starts = np.unique(fs.t_ns, return_index=True)
        ends = np.append(starts[1:], len(fs.t_ns))
        ev += [(int(t), FRAME, (fs.track_id[a:b], fs.uv_left[a:b], fs.uv_right[a:b]))
               for t, a, b in zip(times, starts, ends, strict=True)]
    ev.sort(key=lambda e: (e[0], e[1]))
    return ev


def _config(case: Case, f: dict[str, Any]) -> RunConfig:
    cfg = RunConfig(method=case.method, model=case.model,  # type: ignore[arg-type]
                    init=InitOptions(mode=case.init), duration_s=case.duration_s)  # type: ignore[arg-type]
    if case.method == "ins":
        return cfg
    fs = f["features"]
    cfg = replace(cfg, vision=VisionOptions(source="features",
                                            pixel_noise_std=float(fs.pixel_noise_std),
                                            **{"rotation": "imu", **case.vision}))
    period = float(np.median(np.diff(np.unique(fs.t_ns)))) * 1e-9
    return tune_for_frames(cfg, f["imu_cal"], period)


def _rig(f: dict[str, Any], gravity: tuple[float, float, float]) -> Rig:
    t = np.asarray(f["imu"].t_ns, np.int64)
    period = float(np.median(np.diff((t - t[0]) * 1e-9)))
    return Rig(gravity, period, f["imu_cal"], f["cam0"], f["cam1"], f.get("gps_cal"),
               f.get("mag_cal"), f.get("sonar_cal"))


def feed_by_hand(case: Case, tmp: Path) -> Any:
    synthetic = case.data == "euroc_synth"
    root = EUROC_MICRO if synthetic else village_root(tmp)
    f = _files(root, synthetic)
    cfg = _config(case, f)
    gravity = (0.0, 0.0, -9.81)
    init = None
    if case.init == "groundtruth":
        imu = f["imu"]
        data = InitData("by hand", gravity, ImuArrays(imu.t_ns, imu.gyro_B, imu.accel_B),
                        f["imu_cal"], groundtruth=f["gt"])
        init = initialise(data, BIASED if case.model == "biased" else PAPER, cfg.init)
    nav = Navigator(cfg, _rig(f, gravity), initial_state=init)
    seen: list[int] = []
    nav_outputs = nav.outputs()
    for t, kind, p in _events(f, case.method != "ins"):
        feed(nav, kind, t, p if kind != FRAME else ("features", *p))  # the public feed_* calls
        if nav.status == "finished":
            break
    res = nav.close()
    seen = [s.t_ns for s in nav_outputs]
    assert seen == res.t_ns.tolist()  # every logged state went through the output iterator
    return res


HAND_CASES = [c for c in CASES if c.name in (
    "euroc_ins", "euroc_lc", "euroc_tc", "euroc_3d", "village_ins", "village_lc", "village_tc",
    "village_3d", "village_3d_clone")]


@pytest.mark.slow
@pytest.mark.parametrize("case", case_params(HAND_CASES))
def test_fed_by_hand_equals_svains_run(case: Case, tmp_path_factory: pytest.TempPathFactory
                                       ) -> None:
    res = feed_by_hand(case, tmp_path_factory.getbasetemp())
    assert_matches_golden(case, summarise(res.t_ns, res.x, res.P9, res.report))
