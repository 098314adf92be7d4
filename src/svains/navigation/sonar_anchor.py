"""The start's height from the sonar, for a start whose position no sensor fixed.

A static start without GPS, or a vision start, puts the body at the local origin, height 0,
with a small position standard deviation: the local frame is the start's. The sonar measures
the height above a ground plane the calibration places in the world (``ground_height``), so a
body that starts 2.8 m above that ground contradicts every range, the gate refuses them all and
the run goes on without the sonar, unwarned (a user's probe: sonar 0 of 600 fused; at 1 Hz
frames the wider prediction let it in late, 2.8 m at once, NEES 2180). The first range after
such a start moves the local frame along the up axis instead, where the ground truly is
(``anchor_height``, with the median of the first ranges): the height of a local frame is as
free as its origin.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from svains.geometry.rotation import quat_to_rotmat
from svains.models.clones import CloneManifold
from svains.models.state import P, Q
from svains.sensors.types import SonarCalib

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
# a shift is made when the range misses by more than this many standard deviations
ANCHOR_SIGMAS = 3.0
# the start's height from the median of the first ANCHOR_RANGES ranges, when more than half of
# them lie within ANCHOR_AGREE_M of it (a resting or hovering start; one no-echo reading first
# set the height for the whole run, the sonar then refused 599 of 600: a user's probe)
ANCHOR_RANGES = 5
ANCHOR_AGREE_M = 0.2


def anchor_height(
    x: F64, P_: F64, manifold: object, cal: SonarCalib, g_W: F64, range_m: float
) -> tuple[F64, float] | None:
    """The state ``x`` (nx,) moved along the up axis (``-g_W``) so that the sonar reads
    ``range_m`` (m), and the move (m); None when the range agrees with the state within
    ``ANCHOR_SIGMAS`` (the ordinary update takes it) or the beam does not point at the ground.
    ``P_`` (ndx, ndx) gives the height's standard deviation; clone positions move too."""
    up = -np.asarray(g_W, dtype=float) / np.linalg.norm(g_W)
    R_W_B = quat_to_rotmat(x[Q])
    T_B_S = np.asarray(cal.T_B_S, dtype=float)
    p_W_S = x[P] + R_W_B @ T_B_S[:3, 3]
    cos = float(up @ (R_W_B @ T_B_S[:3, 2]))  # the beam against the up axis
    if cos > -0.5:
        return None  # pointing up or along the ground: no height from it
    predicted = (cal.ground_height - float(up @ p_W_S)) / cos
    height_var = float(up @ P_[0:3, 0:3] @ up)
    std = float(np.sqrt(cal.noise_std**2 + height_var / cos**2))
    if abs(range_m - predicted) <= ANCHOR_SIGMAS * std:
        return None
    shift = (predicted - range_m) * cos  # along up: d(range)/d(height) = -1 / cos
    out = x.copy()
    out[P] += shift * up
    if isinstance(manifold, CloneManifold):
        for i in range(manifold.n_clones):
            out[manifold.columns(i)[0]] += shift * up
    return out, shift
