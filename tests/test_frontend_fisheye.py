"""Equidistant fisheye pairs: rectification to the ideal pinhole pair and the simulated images."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset, stereo_pairs
from svains.frontend.rectify import StereoRectifier
from svains.frontend.run import run_frontend
from svains.geometry.camera import RectifiedStereo
from svains.sim.config import SimConfig
from svains.sim.fisheye import FisheyeRenderer
from svains.sim.render import Renderer
from svains.sim.simulate import build_scene, camera_calibs, simulate

COEFFS = [-0.00626, 0.04132, -0.03836, 0.00649]


def _scene():  # type: ignore[no-untyped-def]
    cfg = SimConfig()
    cfg = replace(cfg, seed=3, duration_s=4.0,
                  camera=replace(cfg.camera, lens="equidistant", fisheye_distortion=COEFFS))
    return build_scene(cfg)


def test_fisheye_pair_rectifies_to_the_ideal_rig() -> None:
    rig = _scene().rig
    cam0, cam1 = camera_calibs(rig, 5.0, "equidistant", COEFFS)
    rect = StereoRectifier.from_calibration(cam0, cam1)
    assert not rect.identity
    got = rect.rig
    assert (got.f, got.cu, got.cv, got.width, got.height) == (
        rig.f, rig.cu, rig.cv, rig.width, rig.height)
    assert got.baseline == pytest.approx(rig.baseline, abs=1e-12)
    np.testing.assert_allclose(got.R_B_C, rig.R_B_C, atol=1e-12)
    # Rectified -> raw fisheye -> rectified, to the image corners (~56° off the axis raw).
    rng = np.random.default_rng(0)
    uv = np.vstack([rng.uniform([0, 0], [rig.width - 1, rig.height - 1], (40, 2)),
                    [[0, 0], [rig.width - 1, rig.height - 1]]])  # fmt: skip
    for right in (False, True):
        raw = rect.unrectify_points(uv, right)
        # The fisheye compresses the periphery: raw pixels are closer to the centre.
        r_raw = np.hypot(raw[:, 0] - rig.cu, raw[:, 1] - rig.cv)
        r_rect = np.hypot(uv[:, 0] - rig.cu, uv[:, 1] - rig.cv)
        assert np.all(r_raw[r_rect > 100] < r_rect[r_rect > 100])
        np.testing.assert_allclose(rect.rectify_points(raw, right), uv, atol=1e-6)


def test_rendered_fisheye_rectifies_to_the_pinhole_render() -> None:
    """The simulated fisheye image, rectified with its calibration, is the pinhole image of the
    same view (up to resampling): the lens model of render, calibration and rectifier agree."""
    scene = _scene()
    rig: RectifiedStereo = scene.rig
    cam0, cam1 = camera_calibs(rig, 5.0, "equidistant", COEFFS)
    rect = StereoRectifier.from_calibration(cam0, cam1)
    truth = scene.trajectory.evaluate(np.array([1.0]))
    R_W_C = truth.R_W_B[0] @ rig.R_B_C
    p_W_C = truth.p_W_B[0] + truth.R_W_B[0] @ rig.p_B_C
    fish = FisheyeRenderer(scene.world, rig, COEFFS).render(R_W_C, p_W_C, 1.0)
    pin = Renderer(scene.world, rig).render_with_depth(R_W_C, p_W_C, 1.0, full_depth=False)[0]
    assert fish.shape == pin.shape
    back = rect.rectify_left(fish).astype(float)
    core = (slice(20, -20), slice(20, -20))
    err = np.abs(back[core] - pin[core].astype(float))
    raw_err = np.abs(fish[core].astype(float) - pin[core].astype(float))
    assert np.median(err) < 3.0  # grey levels: resampling only
    assert np.mean(err) < 0.5 * np.mean(raw_err)  # the fisheye image itself differs much more


@pytest.mark.slow
def test_frontend_on_a_simulated_fisheye_set(tmp_path: Path) -> None:
    """End to end: simulated fisheye pair written as ASL (equidistant sensor.yaml), read,
    rectified and tracked; every frame gives a motion close to the truth."""
    cfg = SimConfig()
    cfg = replace(
        cfg, seed=2, duration_s=2.0,
        camera=replace(cfg.camera, rate_hz=5.0, lens="equidistant", fisheye_distortion=COEFFS),
        gps=replace(cfg.gps, enabled=False), mag=replace(cfg.mag, enabled=False),
    )  # fmt: skip
    ds = load_dataset(simulate(cfg, tmp_path / "fish"))
    assert ds.cam0 is not None and ds.cam0.distortion_model == "equidistant"
    np.testing.assert_array_equal(ds.cam0.distortion, COEFFS)
    run = run_frontend(ds, stereo_pairs(ds))
    recs = run.records[1:]
    assert len(recs) == 10 and all(r.stats.status == "ok" for r in recs)
    rel = [r.translation_error_m / r.gt_translation_m for r in recs]
    # Measured: median 0.4 % of the step and 0.008° on a 20 s flight (svains frontend).
    assert np.median(rel) < 0.02
    assert np.median([r.rotation_error_deg for r in recs]) < 0.05


def test_3d_from_fisheye_images_tracks_like_the_pinhole_pair(tmp_path: Path) -> None:
    """End to end through the estimator: ``3d`` from the same short flight rendered through a
    fisheye pair and through the ideal pinhole pair, GPS-denied from the true start; the fisheye
    run fuses every frame and stays within 1.5x the pinhole run's position error."""
    from svains.evaluation.run import run_method
    from svains.navigation.options import InitOptions, RunConfig, VisionOptions

    config = RunConfig(method="3d", init=InitOptions(mode="groundtruth"), use_gps=False,
                       use_mag=False, vision=VisionOptions(source="images"))  # fmt: skip
    rmse = {}
    for lens in ("pinhole", "equidistant"):
        cfg = SimConfig()
        cfg = replace(
            cfg, seed=2, duration_s=4.0,
            camera=replace(cfg.camera, rate_hz=5.0, lens=lens, fisheye_distortion=COEFFS),
            gps=replace(cfg.gps, enabled=False), mag=replace(cfg.mag, enabled=False),
        )  # fmt: skip
        rep = run_method(load_dataset(simulate(cfg, tmp_path / lens)), "3d", config).report
        assert rep["vision"]["frames_fused"] >= 18  # 20 frames: the first has no motion yet
        rmse[lens] = rep["position_rmse_m"]
    assert rmse["equidistant"] < 1.5 * rmse["pinhole"] + 0.01
