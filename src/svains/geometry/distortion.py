"""Lens distortion of raw cameras on normalised image coordinates (numpy, no OpenCV).

Two models, named as in Kalibr/EuRoC ``sensor.yaml`` files:

- ``radtan`` (``radial-tangential``): OpenCV/Bouguet order ``(k1, k2, p1, p2[, k3])``,
  ``x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)`` (and ``y`` alike).
- ``equidistant`` (Kannala-Brandt, ``cv2.fisheye``): ``(k1, k2, k3, k4)``, with ``θ`` the angle
  of the ray from the optical axis, ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` and
  ``x_d = (θ_d / r) x``, ``r = |(x, y)|``.

Normalised coordinates are ``(X/Z, Y/Z)`` of a camera point (x right, y down, z forward); pixels
follow as ``u = fu x_d + cu``, ``v = fv y_d + cv``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.errors import CalibrationError

F64 = NDArray[np.float64]

RADTAN = "radtan"
EQUIDISTANT = "equidistant"
# Names a sensor.yaml may use for each model (Kalibr writes ``radtan``, EuRoC the long form).
MODEL_ALIASES = {
    "radial-tangential": RADTAN, "radtan": RADTAN, "none": RADTAN, "": RADTAN,
    "equidistant": EQUIDISTANT, "equi": EQUIDISTANT, "fisheye": EQUIDISTANT,
    "kannala-brandt": EQUIDISTANT,
}  # fmt: skip
# Allowed numbers of coefficients per model.
N_COEFFS = {RADTAN: (4, 5), EQUIDISTANT: (4,)}


def canonical_model(name: str) -> str:
    """``radtan`` or ``equidistant`` for a model name of a calibration file; raises
    ``CalibrationError`` for anything else."""
    key = str(name).strip().lower()
    if key not in MODEL_ALIASES:
        raise CalibrationError(
            f"distortion model {name!r} is not supported (radial-tangential/radtan or "
            "equidistant)"
        )
    return MODEL_ALIASES[key]


def check_coefficients(model: str, coeffs: ArrayLike) -> F64:
    """The coefficients as a float array after checking their number for ``model``."""
    m = canonical_model(model)
    c = np.asarray(coeffs, dtype=float).reshape(-1)
    if c.size not in N_COEFFS[m]:
        allowed = " or ".join(str(n) for n in N_COEFFS[m])
        raise CalibrationError(
            f"{m} distortion needs {allowed} coefficients "
            f"({'k1, k2, p1, p2[, k3]' if m == RADTAN else 'k1, k2, k3, k4'}), has {c.size}"
        )
    if not np.all(np.isfinite(c)):
        raise CalibrationError(f"{m} distortion coefficients must be finite, got {c.tolist()}")
    return c


def distort(xy: ArrayLike, model: str, coeffs: ArrayLike) -> F64:
    """Distorted normalised coordinates (..., 2) of ideal normalised coordinates ``xy``."""
    m = canonical_model(model)
    c = check_coefficients(m, coeffs)
    p = np.asarray(xy, dtype=float)
    x, y = p[..., 0], p[..., 1]
    r2 = x * x + y * y
    if m == RADTAN:
        k1, k2, p1, p2 = c[:4]
        k3 = c[4] if c.size == 5 else 0.0
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)
    r = np.sqrt(r2)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3]))))
    # r -> 0: theta_d / r -> 1 (the model is the identity on the axis).
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
    return np.stack([x * scale, y * scale], axis=-1)


def equidistant_theta(theta_d: ArrayLike, coeffs: ArrayLike, iterations: int = 20) -> F64:
    """Ray angle ``θ`` (rad) from the distorted angle ``θ_d`` of the equidistant model, by
    Newton's method from ``θ = θ_d`` (the model is monotonic over any usable field of view)."""
    k = check_coefficients(EQUIDISTANT, coeffs)
    td = np.asarray(theta_d, dtype=float)
    theta = td.copy()
    for _ in range(iterations):
        t2 = theta * theta
        f = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - td
        df = 1.0 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
        theta = theta - f / df
    return theta


def equidistant_rays(xy_d: ArrayLike, coeffs: ArrayLike) -> F64:
    """Unit rays (..., 3) in the camera frame of distorted normalised coordinates ``xy_d``
    (..., 2) of the equidistant model; valid beyond 90° from the axis (``z`` < 0 there)."""
    p = np.asarray(xy_d, dtype=float)
    theta_d = np.hypot(p[..., 0], p[..., 1])
    theta = equidistant_theta(theta_d, coeffs)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(theta_d > 1e-12, np.sin(theta) / np.where(theta_d > 1e-12, theta_d, 1.0),
                     1.0)  # fmt: skip
    return np.stack([p[..., 0] * s, p[..., 1] * s, np.cos(theta)], axis=-1)
