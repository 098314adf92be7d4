"""Zero-velocity updates while the platform rests (the static start, and stops).

Without them a resting vehicle is dead-reckoned: its velocity and position drift with the IMU
noise, and the first vision update after a long rest meets a wide, wrongly shaped prediction
(issue 22: frames 5 s apart on a MAV that rests for 5 s). ``StaticTest`` reads the IMU of the
last ``window_s``: the platform rests when the means of its ``block_s`` blocks stay within
``limit_factor`` times the static start's limits (``InitOptions.max_accel_dev``,
``max_gyro_dev``; vibrating rotors make single samples useless; the margin because the resting
EuRoC MAV's 0.5 s windows reach 0.30 m/s², the start's whole limit, while taking off gives
0.7 m/s² and more) and the specific force is gravity's magnitude. A constant-velocity
motion passes that test too; the chi-square gate of the update then refuses it wherever the
filter knows it moves (OpenVINS tests its zero-velocity hypothesis the same way).

A gentle start passes it as well: a robot setting off at 0.1-0.75 m/s² keeps its block means
within the limits, and the start's updates went on while it drove (a user's probe: one accepted
at 1 m/s, the accelerometer bias pulled to absorb the motion). So the start's rest also ends
when the specific force, integrated since the start against its mean over the static interval
(``InitOptions.static_s``), has gained more velocity than its block means' spread allows
(``moved_since_start``): ``motion_sigmas`` times the block deviation times √(block · elapsed),
at least ``motion_floor_mps``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from svains.models.zero_velocity import body_velocity
from svains.navigation.base import MeasurementBlock
from svains.navigation.imu_history import ImuHistory
from svains.navigation.options import InitOptions, ZuptOptions
from svains.navigation.platform_noise import block_deviation, block_means

F64 = NDArray[np.float64]


class StaticTest:
    """Whether the IMU history shows a resting platform at a time (see the module docstring)."""

    def __init__(self, options: ZuptOptions, init: InitOptions, gravity_mps2: float) -> None:
        self.options = options
        self.init = init
        self.gravity_mps2 = float(gravity_mps2)
        # the static interval's mean specific force (body) and block deviation, once complete
        self._reference: tuple[int, F64, float] | None = None
        # the velocity gained against that mean (m/s, (3,)) over the rows before ``_rows_done``
        # (rows up to the filter's time are final: each call adds only the rows since the last)
        self._gained = np.zeros(3)
        self._rows_done = 0

    def moved_since_start(self, history: ImuHistory, t_ns: int) -> bool:
        """Whether the specific force since the first sample (``history``'s, the start's rest)
        up to ``t_ns``, less its mean over the static interval, integrates to more velocity
        than the block means' spread explains (False until the static interval is complete, or
        once the samples of the start are gone)."""
        t = history.t_ns
        if t.size < 4 or history.dropped:
            return False
        if self._reference is None:
            end = int(t[0]) + int(self.init.static_s * 1e9)
            if t_ns < end:
                return False
            k = int(np.searchsorted(t, end, "right"))
            acc = history.accel_B[:k]
            dt_s = max(1e-9, float(np.median(np.diff(t[:k]))) * 1e-9)
            n_block = max(1, round(self.init.block_s / dt_s))
            if k // n_block < 2:
                return False
            dev = block_deviation(block_means(acc, n_block))
            self._reference = (int(t[0]), acc.mean(axis=0), dev)
        t0, f_ref, dev = self._reference
        k1 = int(np.searchsorted(t, t_ns, "right"))
        k0 = max(self._rows_done - 1, 0)  # from the last row added, for its interval's end
        if k1 - k0 >= 2:
            self._gained += _gained(t[k0:k1], history.accel_B[k0:k1], f_ref)
            self._rows_done = k1
        dv = self._gained
        elapsed = (t_ns - t0) * 1e-9
        o = self.options
        limit = max(o.motion_floor_mps,
                    o.motion_sigmas * dev * float(np.sqrt(self.init.block_s * elapsed)))
        return bool(np.linalg.norm(dv) > limit)

    def moved_since(self, history: ImuHistory, t_from_ns: int, t_ns: int,
                    accel_density: float) -> bool:  # fmt: skip
        """Whether the specific force over ``(t_from_ns, t_ns]``, less its mean over the
        ``window_s`` before ``t_from_ns`` (a rest another witness saw), integrates to more
        velocity than the accelerometer's white noise ``accel_density`` (m/s²/√Hz, the filter's)
        explains, ``motion_sigmas`` of it: the camera's verdict is a frame old when the vehicle
        pulls away, and the rest test's limits, made for a MAV's rotors, pass a robot's first
        0.4 m/s² (a probe: 0.05 m/s fused as rest 0.2 s into a pull-away; the window's own
        block spread, which the pull-away's start had already widened, let it through). False
        where the samples do not tell (fewer than four before, none after)."""
        t = history.t_ns
        window_ns = int(self.options.window_s * 1e9)
        k_from = int(np.searchsorted(t, t_from_ns, "right"))
        k0 = int(np.searchsorted(t, t_from_ns - window_ns, "right"))
        k1 = int(np.searchsorted(t, t_ns, "right"))
        if k_from - k0 < 4 or k1 - k_from < 1:
            return False
        f_ref = history.accel_B[k0:k_from].mean(axis=0)
        k_start = max(k_from - 1, 0)  # the interval that holds t_from
        dv = _gained(t[k_start:k1], history.accel_B[k_start:k1], f_ref)
        elapsed = (t_ns - t_from_ns) * 1e-9
        # white noise over the interval, and the reference mean's own over the window
        std = accel_density * float(np.sqrt(elapsed * (1.0 + elapsed / self.options.window_s)))
        return bool(np.linalg.norm(dv) > self.options.motion_sigmas * np.sqrt(3.0) * std)

    def at_rest(self, history: ImuHistory, t_ns: int) -> bool | None:
        """The samples in ``(t_ns - window_s, t_ns]``: block means (rotated to the body frame)
        within the limits, and their mean specific force within the accelerometer limit of
        gravity's magnitude. None (undecided) before ``window_s`` of samples or with fewer than two
        blocks."""
        o, i = self.options, self.init
        acc_limit, gyro_limit = o.limit_factor * i.max_accel_dev, o.limit_factor * i.max_gyro_dev
        t = history.t_ns
        k1 = int(np.searchsorted(t, t_ns, "right"))
        k0 = int(np.searchsorted(t, t_ns - int(o.window_s * 1e9), "right"))
        if k1 - k0 < 4 or t[0] > t_ns - int(o.window_s * 1e9):
            return None
        dt_s = max(1e-9, float(np.median(np.diff(t[k0:k1]))) * 1e-9)
        n_block = max(1, round(i.block_s / dt_s))
        n_blocks = (k1 - k0) // n_block
        if n_blocks < 2:
            return None
        k0 = k1 - n_blocks * n_block  # whole blocks ending at the newest sample
        acc = block_means(history.accel_B[k0:k1], n_block)
        gyro = block_means(history.gyro_B[k0:k1], n_block)
        return bool(
            block_deviation(acc) <= acc_limit
            and block_deviation(gyro) <= gyro_limit
            and abs(float(np.linalg.norm(acc.mean(axis=0))) - self.gravity_mps2) <= acc_limit
        )


def _gained(t_ns: NDArray[np.int64], accel_B: F64, f_ref: F64) -> F64:
    """The velocity (3,) m/s the specific force ``accel_B`` (N, 3) at ``t_ns`` (N,), less
    ``f_ref`` (3,), integrates to over the samples (trapezoids)."""
    dt = np.diff(t_ns) * 1e-9
    return np.sum((0.5 * (accel_B[1:] + accel_B[:-1]) - f_ref) * dt[:, None], axis=0)


def zero_velocity_block(velocity_std_mps: float) -> MeasurementBlock:
    """``v_W_B = 0`` with noise ``velocity_std_mps`` per axis."""
    return MeasurementBlock("zupt", body_velocity, np.zeros(3), np.full(3, velocity_std_mps**2))
