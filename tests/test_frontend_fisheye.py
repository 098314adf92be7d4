"""Equidistant fisheye pairs: rectification to the ideal pinhole pair and the simulated images."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from svains.frontend.rectify import StereoRectifier
from svains.geometry.camera import RectifiedStereo
from svains.sim.config import SimConfig
from svains.sim.fisheye import FisheyeRenderer
from svains.sim.render import Renderer
from svains.sim.simulate import build_scene, camera_calibs

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
