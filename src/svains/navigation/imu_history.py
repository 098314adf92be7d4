"""``ImuHistory``: the IMU samples received so far, in the body frame, with eq. 3's α.

Append-only and time-ordered (the caller drops duplicate or backward stamps). ``append`` only
stores the raw sample; the body-frame rotation and α are computed for the new rows in one
vectorised pass when the arrays are read. α at sample k uses samples k-2..k only (the backward
stencil of ``models.imu.angular_acceleration``, with the same element-wise floating-point
operations, so it equals the whole-recording result bit for bit); samples 0 and 1 share the
first difference. Storage grows by doubling; the arrays are views of it.

Bounded memory for long runs: once ``keep_from_ns`` is set (the estimator sets it as it goes),
a full store first drops the rows stamped before it (at least the last two rows stay, for the
stencil) instead of growing; ``dropped`` counts the rows gone, so an absolute sample index is
``local index + dropped``. Dropping changes no value: the stencil's times keep the first
sample's origin.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.geometry.rotation import so3_exp

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class ImuHistory:
    """Samples ``t_ns`` (N,) int64, ``gyro_B`` (N, 3) rad/s, ``accel_B`` (N, 3) m/s² (rotated
    from the sensor frame S by ``R_B_S``) and ``alpha_B`` (N, 3) rad/s²."""

    def __init__(self, R_B_S: ArrayLike | None = None, capacity: int = 4096) -> None:
        R = np.eye(3) if R_B_S is None else np.asarray(R_B_S, float)
        # An identity mount is skipped (exact either way).
        self._R_T: F64 | None = None if np.array_equal(R, np.eye(3)) else R.T.copy()
        self.n = 0
        self._done = 0  # rows rotated and with α
        self.dropped = 0  # rows dropped from the front (``keep_from_ns``)
        self.keep_from_ns: int | None = None  # rows before it may be dropped (None: keep all)
        self._t_origin: int | None = None  # the stencil's time origin (first sample ever)
        self._t = np.empty(capacity, np.int64)
        self._ts = np.empty(capacity)  # the stencil's times, s from the first sample
        self._raw = np.empty((capacity, 6))  # gyro_S | accel_S as received
        self._data = np.empty((capacity, 9))  # gyro_B | accel_B | alpha_B
        # spans (start, end) ns where samples were dropped or missing (the fault handler's
        # marks): the checks that integrate the samples leave intervals touching them out
        self._faults: list[tuple[int, int]] = []

    @property
    def t_ns(self) -> I64:
        return self._t[: self.n]

    @property
    def gyro_B(self) -> F64:
        self._sync()
        return self._data[: self.n, 0:3]

    @property
    def accel_B(self) -> F64:
        self._sync()
        return self._data[: self.n, 3:6]

    @property
    def alpha_B(self) -> F64:
        self._sync()
        return self._data[: self.n, 6:9]

    @property
    def last_ns(self) -> int | None:
        return int(self._t[self.n - 1]) if self.n else None

    def append(self, t_ns: int, gyro_S: ArrayLike, accel_S: ArrayLike) -> None:
        """Add one sample (``t_ns`` must be later than the last one)."""
        k = self.n
        if k == self._t.size:
            k = self._drop_old()
        if k == self._t.size:
            self._t = np.resize(self._t, 2 * k)
            self._ts = np.resize(self._ts, 2 * k)
            raw = np.empty((2 * k, 6))
            raw[:k] = self._raw
            self._raw = raw
            data = np.empty((2 * k, 9))
            data[:k] = self._data
            self._data = data
        if self._t_origin is None:
            self._t_origin = int(t_ns)
        self._t[k] = t_ns
        self._raw[k, 0:3] = gyro_S
        self._raw[k, 3:6] = accel_S
        self.n = k + 1

    def drop_last(self) -> None:
        """Remove the newest sample (a spike found by the sample after it). The estimator must
        not have propagated past the sample before it."""
        if self.n:
            self.n -= 1
            self._done = min(self._done, self.n)

    def mark_fault(self, start_ns: int, end_ns: int) -> None:
        """Note that the samples of ``[start_ns, end_ns]`` are missing or were dropped (the
        newest 1024 spans are kept)."""
        self._faults.append((int(start_ns), int(end_ns)))
        if len(self._faults) > 1024:
            del self._faults[:512]

    def fault_in(self, lo_ns: int, hi_ns: int) -> bool:
        """Whether a marked fault span touches ``[lo_ns, hi_ns]``."""
        return any(s <= hi_ns and e >= lo_ns for s, e in reversed(self._faults))

    def fit_last(
        self, window_s: float, noise_std: ArrayLike, tolerance: float = 2.0
    ) -> tuple[NDArray[np.bool_], int]:
        """Replace channels of the last sample by the value at its stamp of a least-squares line
        through the samples of the last ``window_s`` seconds (sensor frame): the white noise of
        one sample drops to that of a fitted end point, and a linear trend is kept (no lag).

        Only where the line explains the samples up to their white noise (residual RMS at most
        ``tolerance`` times ``noise_std`` (6,), gyro then accel, per sample): where the samples
        stray further (vibration, a turn) the spread is signal, and the sample stays as it is.
        Returns which of the 6 channels were replaced (none with fewer than 3 samples) and how
        many samples the line went through. The estimator must not have propagated past the
        previous sample yet."""
        n = self.n
        replaced = np.zeros(6, bool)
        if n < 3:
            return replaced, 0
        t = self._t[:n]
        k0 = int(np.searchsorted(t, t[-1] - int(window_s * 1e9)))
        m = n - k0
        if m < 3:
            return replaced, m
        x = (t[k0:] - t[-1]) * 1e-9  # s, the last sample at 0
        A = np.column_stack([np.ones(m), x])
        Y = self._raw[k0:n]
        coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
        rms = np.sqrt(((Y - A @ coef) ** 2).sum(axis=0) / (m - 2))
        replaced = rms <= tolerance * np.asarray(noise_std, float)
        if replaced.any():
            self._raw[n - 1, replaced] = coef[0, replaced]  # the line at x = 0
            self._done = min(self._done, n - 1)  # rotate again and redo α from this row
        return replaced, m

    def raw(self, k: int) -> F64:
        """Sample ``k`` as received (6,): gyro then accelerometer, sensor frame (a copy)."""
        return np.array(self._raw[k], dtype=float)

    def replace_by_mean(self, k: int, lo_ns: int, hi_ns: int) -> int:
        """Replace sample ``k`` (sensor frame) by the mean of the samples stamped in
        ``[lo_ns, hi_ns]``; returns how many were averaged (the sample stays when fewer than 2).

        For the ends of a long gap's bridge: held for seconds, one sample's vibration and white
        noise would be integrated as motion, while a mean over many vibration cycles is the
        low-frequency signal the bridge needs. The estimator must not have propagated past
        sample ``k - 1`` yet."""
        t = self._t[: self.n]
        k0, k1 = int(np.searchsorted(t, lo_ns)), int(np.searchsorted(t, hi_ns, side="right"))
        if k1 - k0 < 2 or not 0 <= k < self.n:
            return 0
        self._raw[k] = self._raw[k0:k1].mean(axis=0)
        self._done = min(self._done, k)  # rotate again and redo α from this row
        return k1 - k0

    def _sync(self) -> None:
        """Rotate the new rows and compute their α (one pass over the rows since the last)."""
        a, n = self._done, self.n
        if a == n:
            return
        raw = self._raw[a:n]
        if self._R_T is None:
            self._data[a:n, 0:6] = raw
        else:
            self._data[a:n, 0:3] = raw[:, 0:3] @ self._R_T
            self._data[a:n, 3:6] = raw[:, 3:6] @ self._R_T
        g = self._data[:, 0:3]
        t = self._ts
        t[a:n] = (self._t[a:n] - self._t_origin) * 1e-9
        if n >= 2 and a < 2:
            self._data[0:2, 6:9] = (g[1] - g[0]) / (t[1] - t[0])
        elif n < 2:
            self._data[0, 6:9] = 0.0
        k0 = max(a, 2)
        if n > k0:
            h1 = (t[k0 - 1 : n - 1] - t[k0 - 2 : n - 2])[:, None]
            h2 = (t[k0:n] - t[k0 - 1 : n - 1])[:, None]
            self._data[k0:n, 6:9] = (
                g[k0 - 2 : n - 2] * h2 / (h1 * (h1 + h2))
                - g[k0 - 1 : n - 1] * (h1 + h2) / (h1 * h2)
                + g[k0:n] * (h1 + 2.0 * h2) / (h2 * (h1 + h2))
            )
        self._done = n

    def _drop_old(self) -> int:
        """Drop the rows before ``keep_from_ns`` (keeping the last two) when that frees at
        least a quarter of the store; returns the new row count."""
        if self.keep_from_ns is None:
            return self.n
        self._sync()
        cut = min(int(np.searchsorted(self._t[: self.n], self.keep_from_ns)), self.n - 2)
        if cut < self._t.size // 4:
            return self.n
        m = self.n - cut
        for arr in (self._t, self._ts, self._raw, self._data):
            arr[:m] = arr[cut : self.n]
        self.n = self._done = m
        self.dropped += cut
        return m


def shifted_integrals(t_s: F64, y: F64, end_s: float, shifts_s: F64) -> F64:
    """Integrals (S, k) of the samples ``y`` (N, k) at times ``t_s`` (N,) s over the windows
    ``[δ, end_s + δ]`` for each shift ``δ`` of ``shifts_s`` (S,): trapezoids over one
    cumulative integral, the window ends interpolated (the samples must span every window)."""
    steps = 0.5 * (y[1:] + y[:-1]) * np.diff(t_s)[:, None]
    cum = np.vstack([np.zeros(y.shape[1]), np.cumsum(steps, axis=0)])
    return np.stack([np.interp(end_s + shifts_s, t_s, c) - np.interp(shifts_s, t_s, c)
                     for c in cum.T], axis=1)  # fmt: skip


def gyro_attitudes(R_W_B: F64, gyro_B: F64, t_s: F64) -> F64:
    """Attitudes (N, 3, 3) at the samples ``t_s`` (N,) s: ``R_W_B`` (3, 3) at time 0 turned by
    the gyro's rates ``gyro_B`` (N, 3) rad/s (biases removed; the rate at the start of each
    interval, as the filter's own propagation), forwards and backwards from the last sample at
    or before 0."""
    j = min(max(int(np.searchsorted(t_s, 0.0, side="right")) - 1, 0), t_s.size - 1)
    R = np.empty((t_s.size, 3, 3))
    R[j] = R_W_B @ so3_exp(gyro_B[j] * t_s[j])  # back from time 0 to that sample
    inc = so3_exp(gyro_B[:-1] * np.diff(t_s)[:, None])  # sample k -> k+1
    for k in range(j, t_s.size - 1):
        R[k + 1] = R[k] @ inc[k]
    for k in range(j - 1, -1, -1):
        R[k] = R[k + 1] @ inc[k].T
    return R
