"""Lens models on normalised coordinates against OpenCV's projections (radtan 4/5, fisheye)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from svains.errors import CalibrationError
from svains.geometry.distortion import (
    canonical_model,
    check_coefficients,
    distort,
    equidistant_rays,
)

K = np.array([[400.0, 0.0, 320.0], [0.0, 410.0, 240.0], [0.0, 0.0, 1.0]])


def _points(n: int, seed: int, spread: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-spread, spread, (n, 2))
    return np.column_stack([xy, np.ones(n)])


@pytest.mark.parametrize(
    "coeffs",
    [[-0.28, 0.07, 2e-4, 1.8e-5], [-0.3728755, 0.2037299, 0.002219027, 0.001383707, -0.07233722]],
)
def test_radtan_matches_opencv(coeffs: list[float]) -> None:
    P = _points(50, 0, 0.7)
    D = np.asarray(coeffs)
    ref = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    xd = distort(P[:, :2], "radial-tangential", D)
    uv = np.column_stack([K[0, 0] * xd[:, 0] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]])
    np.testing.assert_allclose(uv, ref, atol=1e-9)


def test_k3_matters_in_the_corners() -> None:
    """KITTI's k3 moves a corner ray by tens of pixels: dropping it must change the result."""
    D5 = np.array([-0.3728755, 0.2037299, 0.002219027, 0.001383707, -0.07233722])
    corner = np.array([[-0.95, -0.33]])  # the ray of the top-left raw pixel, roughly
    shift_px = 984.0 * np.linalg.norm(distort(corner, "radtan", D5) - distort(corner, "radtan",
                                                                            D5[:4]))
    assert shift_px > 20.0


def test_equidistant_matches_opencv_fisheye_and_inverts() -> None:
    P = _points(60, 1, 1.5)  # up to ~65° off the axis
    D = np.array([-0.00626, 0.04132, -0.03836, 0.00649])
    ref = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0]
    xd = distort(P[:, :2], "equidistant", D)
    uv = np.column_stack([K[0, 0] * xd[:, 0] + K[0, 2], K[1, 1] * xd[:, 1] + K[1, 2]])
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)
    ray = equidistant_rays(xd, D)
    np.testing.assert_allclose(ray, P / np.linalg.norm(P, axis=1, keepdims=True), atol=1e-12)
    # On the axis the model is the identity.
    np.testing.assert_allclose(distort(np.zeros((1, 2)), "equidistant", D), 0.0)


def test_model_names_and_bad_coefficients() -> None:
    assert canonical_model("radial-tangential") == canonical_model("radtan") == "radtan"
    assert canonical_model("equidistant") == "equidistant"
    with pytest.raises(CalibrationError, match="distortion model 'omni' is not supported"):
        canonical_model("omni")
    with pytest.raises(CalibrationError, match="radtan distortion needs 4 or 5 coefficients"):
        check_coefficients("radtan", np.zeros(3))
    with pytest.raises(CalibrationError, match="equidistant distortion needs 4 coefficients"):
        check_coefficients("equidistant", np.zeros(5))
    with pytest.raises(CalibrationError, match="must be finite"):
        check_coefficients("radtan", [0.1, np.nan, 0.0, 0.0])
