"""Layout of the navigation state vector shared by every model.

Full vector ``x`` (float64), in this order:
``p_W_B`` (3, m) | ``v_W_B`` (3, m/s) | ``q_W_B_wxyz`` (4) | ``omega_B`` (3, rad/s)
| ``bg_B`` (3, rad/s, biased model only) | ``ba_B`` (3, m/s², biased model only).
The paper's state (eq. 14) is the first 13 numbers (12 degrees of freedom). The tangent (error)
vector has the same blocks with the quaternion replaced by a body rotation vector
``δθ_B`` (``R = R̂ Exp(δθ_B)``): 12 or 18 numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

P = slice(0, 3)
V = slice(3, 6)
Q = slice(6, 10)
W = slice(10, 13)
BG = slice(13, 16)
BA = slice(16, 19)

# Tangent-space blocks.
DP = slice(0, 3)
DV = slice(3, 6)
DTH = slice(6, 9)
DW = slice(9, 12)
DBG = slice(12, 15)
DBA = slice(15, 18)


@dataclass(frozen=True)
class StateLayout:
    """Size of the state: ``biased`` adds gyro and accelerometer bias blocks."""

    biased: bool

    @property
    def nx(self) -> int:
        return 19 if self.biased else 13

    @property
    def ndx(self) -> int:
        return 18 if self.biased else 12


PAPER = StateLayout(biased=False)
BIASED = StateLayout(biased=True)
