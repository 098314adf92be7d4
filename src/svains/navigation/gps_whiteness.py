"""``GpsWhiteness``: GPS position innovations correlated from fix to fix.

A consistent filter's innovations are white: each fix tells something the ones before did not.
A receiver's position error wanders over seconds to a minute (multipath, atmosphere), and fixes
faster than it changes, fused as independent, make the filter sure of the wander: its
innovations then lean the same way fix after fix (simulated 10 Hz fixes whose noise is
correlated over 20 s: lag-one correlation of the whitened innovations 0.9-1.0, NEES 150-680).
``gps0/sensor.yaml``'s ``position_correlation_s`` weighs such fixes as what they hold
(``models.gps.correlated_position_scale``); a calibration without it is warned here, once.
Fixes surer than ``position_noise_std`` says do the same through the filter: it takes too
little of each, and its own error carries from fix to fix (KITTI raw, whose fixes are its
reference solution's: 0.89 at the declared 0.35 m, 0.37 at 0.03 m); the warning names both.

The test: over the last ``WINDOW_FIXES`` accepted fixes, the lag-one correlation of their
whitened position innovations, pooled over the three axes,
``ρ = Σ w_k·w_(k-1) / √(Σ |w_k|² Σ |w_(k-1)|²)``
over consecutive pairs no further apart than ``MAX_PAIR_GAP_S``. White innovations give
``ρ`` about 0 with a spread of ``1/√(3N)`` (0.07 for 60 pairs); it warns above
``RHO_WARN``. With the correlation declared the check is off: the weights change, the
innovations' correlation does not.
"""

from __future__ import annotations

import collections

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

# accepted fixes the correlation is taken over, and pairs it needs at least
WINDOW_FIXES = 60
MIN_PAIRS = 30
# s: consecutive fixes further apart (an outage between them) are no pair
MAX_PAIR_GAP_S = 5.0
# a lag-one correlation above this is no white noise (seven spreads of a white window's)
RHO_WARN = 0.5


class GpsWhiteness:
    """Feed each accepted fix's whitened position innovation (``observe``); ``warning``
    returns the one line to warn, once, when the window's correlation exceeds ``RHO_WARN``."""

    def __init__(self) -> None:
        self._fixes: collections.deque[tuple[int, F64]] = collections.deque(maxlen=WINDOW_FIXES)
        self.rho: float | None = None  # the last window's lag-one correlation
        self.mean_square: float | None = None  # ... and its whitened innovations' mean square
        self.rho_max: float | None = None
        self.warned_ns: int | None = None

    def observe(self, t_ns: int, whitened_p: F64) -> str | None:
        """An accepted fix at ``t_ns`` with its whitened position innovation (3,); the
        warning's text the first time the correlation stands out, else None."""
        self._fixes.append((int(t_ns), np.asarray(whitened_p, float)[:3]))
        t = np.array([f[0] for f in self._fixes], np.int64)
        pair = np.diff(t) <= MAX_PAIR_GAP_S * 1e9
        if int(pair.sum()) < MIN_PAIRS:
            return None
        W = np.stack([f[1] for f in self._fixes])
        num = float(np.sum(W[1:][pair] * W[:-1][pair]))
        now, then = float(np.sum(W[1:][pair] ** 2)), float(np.sum(W[:-1][pair] ** 2))
        if now <= 0.0 or then <= 0.0:
            return None
        self.rho = num / np.sqrt(now * then)  # (within ±1)
        self.mean_square = now / (3 * int(pair.sum()))
        self.rho_max = self.rho if self.rho_max is None else max(self.rho_max, self.rho)
        if self.warned_ns is not None or self.rho <= RHO_WARN:
            return None
        self.warned_ns = int(t_ns)
        return (f"the GPS position innovations are correlated from fix to fix (lag-one "
                f"correlation {self.rho:.2f} over the last {int(pair.sum())} pairs; white: "
                "about 0): the fixes' noise is not what gps0/sensor.yaml says: it wanders "
                "slower than they come (give position_correlation_s, s) or is smaller than "
                "position_noise_std")  # fmt: skip

    def summary(self) -> dict[str, object]:
        """For ``report.json`` ``gps_whiteness``."""
        return {"lag1_correlation": self.rho, "lag1_correlation_max": self.rho_max,
                "mean_square": self.mean_square,
                "warned_at_ns": self.warned_ns}
