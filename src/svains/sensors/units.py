"""Unit mistakes a file's syntax cannot show, told from the values: an accelerometer in g or
with gravity removed. Used by the data-set readers (on load) and by the initialisation (online
input); pure numpy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# Median accelerometer magnitude over a stream, in units of |gravity|: a vehicle's specific
# force averages about 1 g (a racing quadrotor's median stays under 2 g); outside this band
# the column is in another unit (g, mg, ft/s²) or has gravity removed.
ACCEL_MEDIAN_RANGE_G = (0.5, 3.0)


def accel_units_problem(accel_S: NDArray[np.float64], g_W: NDArray[np.float64]) -> str | None:
    """Why the specific force ``accel_S`` (N, 3) cannot be m/s² with gravity included, given
    gravity ``g_W`` (3,) m/s², or None (also for no samples)."""
    if len(accel_S) == 0:
        return None
    med = float(np.median(np.linalg.norm(accel_S, axis=1)))
    g = float(np.linalg.norm(g_W))
    lo, hi = ACCEL_MEDIAN_RANGE_G
    if lo * g <= med <= hi * g:
        return None
    # Gravity dominates the mean of a specific force: removed, the mean is near zero.
    steady = float(np.linalg.norm(np.mean(accel_S, axis=0))) > 0.5 * med
    guesses = (("g (multiply by 9.81)", 1.0), ("mg", 1000.0), ("ft/s²", g / 0.3048))
    guess = next((name for name, one_g in guesses if abs(med / one_g - 1.0) < 0.2), None)
    if guess is None or not steady:
        guess = ("gravity removed (linear acceleration)" if med < lo * g and not steady
                 else "another unit")  # fmt: skip
    return (
        f"the accelerometer's median magnitude is {med:.4g} against gravity {g:.4g} m/s²: it "
        f"looks like {guess}; svains reads specific force in m/s², gravity included (a level "
        "IMU at rest reads +9.8 up)"
    )
