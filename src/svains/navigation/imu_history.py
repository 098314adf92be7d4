"""``ImuHistory``: the IMU samples received so far, in the body frame, with eq. 3's α.

Append-only and time-ordered (the caller drops duplicate or backward stamps). α at sample k uses
samples k-2..k only (the backward stencil, ``models.imu.angular_acceleration``, evaluated
per sample with the same floating-point operations, so it equals the whole-array result bit
for bit); samples 0 and 1 share the first difference. Storage grows by doubling; the arrays are
views of it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class ImuHistory:
    """Samples ``t_ns`` (N,) int64, ``gyro_B`` (N, 3) rad/s, ``accel_B`` (N, 3) m/s² (rotated
    from the sensor frame S by ``R_B_S``) and ``alpha_B`` (N, 3) rad/s²."""

    def __init__(self, R_B_S: ArrayLike | None = None, capacity: int = 4096) -> None:
        self.R_S_B_T = np.eye(3) if R_B_S is None else np.asarray(R_B_S, float).T
        self.n = 0
        self._t = np.empty(capacity, np.int64)
        self._ts = np.empty(capacity)  # seconds from the first sample (the stencil's times)
        self._data = np.empty((capacity, 9))  # gyro_B | accel_B | alpha_B

    @property
    def t_ns(self) -> I64:
        return self._t[: self.n]

    @property
    def gyro_B(self) -> F64:
        return self._data[: self.n, 0:3]

    @property
    def accel_B(self) -> F64:
        return self._data[: self.n, 3:6]

    @property
    def alpha_B(self) -> F64:
        return self._data[: self.n, 6:9]

    @property
    def last_ns(self) -> int | None:
        return int(self._t[self.n - 1]) if self.n else None

    def append(self, t_ns: int, gyro_S: ArrayLike, accel_S: ArrayLike) -> None:
        """Add one sample (``t_ns`` must be later than the last one)."""
        k = self.n
        if k == self._t.size:
            self._t = np.resize(self._t, 2 * k)
            self._ts = np.resize(self._ts, 2 * k)
            data = np.empty((2 * k, 9))
            data[:k] = self._data
            self._data = data
        self._t[k] = t_ns
        self._ts[k] = (t_ns - int(self._t[0])) * 1e-9
        rows = np.asarray([gyro_S, accel_S], dtype=float) @ self.R_S_B_T
        self._data[k, 0:3] = rows[0]
        self._data[k, 3:6] = rows[1]
        self.n = k + 1
        g, t = self._data[:, 0:3], self._ts
        if k == 1:
            first = (g[1] - g[0]) / (t[1] - t[0])
            self._data[0:2, 6:9] = first
        elif k >= 2:
            h1 = t[k - 1] - t[k - 2]
            h2 = t[k] - t[k - 1]
            self._data[k, 6:9] = (
                g[k - 2] * h2 / (h1 * (h1 + h2))
                - g[k - 1] * (h1 + h2) / (h1 * h2)
                + g[k] * (h1 + 2.0 * h2) / (h2 * (h1 + h2))
            )
        else:
            self._data[0, 6:9] = 0.0
