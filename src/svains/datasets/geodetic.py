"""WGS-84 latitude/longitude/altitude to a local East-North-Up frame (for NavSatFix messages).

Exact ellipsoidal conversion: geodetic -> ECEF -> ENU about the origin's tangent plane, so the
local frame is z-up like EuRoC (gravity ``(0, 0, -g)`` up to the deflection of the vertical).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]

WGS84_A_M = 6378137.0  # semi-major axis
WGS84_F = 1.0 / 298.257223563  # flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike) -> F64:
    """Earth-centred, earth-fixed coordinates (N, 3) m of WGS-84 points (ellipsoidal height)."""
    lat = np.radians(np.asarray(lat_deg, float))
    lon = np.radians(np.asarray(lon_deg, float))
    h = np.asarray(alt_m, float)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)  # prime-vertical radius
    return np.stack(
        [
            (n + h) * np.cos(lat) * np.cos(lon),
            (n + h) * np.cos(lat) * np.sin(lon),
            (n * (1.0 - WGS84_E2) + h) * np.sin(lat),
        ],
        axis=-1,
    )


def R_enu_ecef(lat_deg: float, lon_deg: float) -> F64:
    """Rotation (3, 3) from ECEF components to the ENU frame at (lat, lon)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.array(
        [
            [-np.sin(lo), np.cos(lo), 0.0],
            [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
            [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)],
        ]
    )


def geodetic_to_enu(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: tuple[float, float, float]
) -> F64:
    """ENU positions (N, 3) m of WGS-84 points about ``origin`` = (lat deg, lon deg, alt m)."""
    lat0, lon0, alt0 = origin
    d = geodetic_to_ecef(lat_deg, lon_deg, alt_m) - geodetic_to_ecef(lat0, lon0, alt0)
    return d @ R_enu_ecef(lat0, lon0).T
