"""IMU noise that matches the platform: the white noise measured while it rests, never below the
calibration.

A data sheet's or an Allan-variance calibration's noise densities describe the sensor on a
bench. On a vehicle, rotor or engine vibration, scale-factor and misalignment errors add to
them: on the real EuRoC V1_01 MAV, dead-reckoning from the true state drifts 4-10x faster than
the Kalibr densities predict, and a filter trusting them is overconfident (issue 22). The
vibration is visible while the vehicle rests before it moves: the static start.

``measure_static_noise`` takes the samples of that interval, averages them over blocks of
``tau_s`` (0.1 s: the scale on which the filter integrates between measurements; the
vibration's high frequencies average out, as they do in the integration) and estimates each
sensor's white-noise density from the spread of the block means: for white noise of density
``σ`` a block mean has variance ``σ² / τ`` per axis, so ``σ̂² = τ · mean_axes(var(block
means))``, a chi-square estimate with ``3 (n_blocks - 1)`` degrees of freedom.

A start that is not static (from a given state, GPS or vision) has no rest of its own: a
recording that begins at rest lends it the first ``init.static_s`` seconds
(``rest_noise``: the static start's test and measure; the replay passes it to the Navigator,
``Navigator(rest_noise=...)``). Without it an in-flight start kept the calibration: EuRoC V1_01
from the true state at 50 s, every frame, NEES 117 (a user's probe).

``platform_noise`` keeps the calibration unless the measured density exceeds it beyond the
estimate's own ``probability`` quantile (on a simulator whose IMU has exactly the calibrated
noise the rule then changes nothing in 999 of 1000 starts). Where it does, the white density
becomes the measured one and the bias random walk is scaled by the square root of the same
ratio: the vibration's low-frequency share is bias-like but cannot be measured in a 2 s window.
Measured on EuRoC V1_01 with features simulated at 5 Hz, every 1st/10th frame (ATE m / NEES 9
dof, frame gate off): random walk x1 0.053/12.8, 0.103/15.4; x√r 0.044/8.1, 0.109/13.8; x r
0.041/6.7, 0.151/9.6 (``bench/low_rate.py``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from svains.navigation.options import InitOptions, NoiseOptions
from svains.sensors.types import ImuCalib

F64 = NDArray[np.float64]
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StaticNoise:
    """White-noise densities measured at rest: ``gyro_density`` rad/s/√Hz, ``accel_density``
    m/s²/√Hz, from block means of ``tau_s`` s; ``dof`` the chi-square degrees of freedom of each
    estimate."""

    gyro_density: float
    accel_density: float
    tau_s: float
    dof: int

    def as_dict(self) -> dict[str, float | int]:
        return {"gyro_density": self.gyro_density, "accel_density": self.accel_density,
                "tau_s": self.tau_s, "dof": self.dof}  # fmt: skip


def block_means(samples: F64, n_block: int) -> F64:
    """Means (B, k) of the B = N // ``n_block`` consecutive full blocks of ``samples`` (N, k)
    (a trailing partial block is left out). The IMU at rest is judged on them: the static start
    (``navigation.init``), the rest test (``navigation.zupt``) and the noise estimate here."""
    n_blocks = len(samples) // n_block
    return samples[: n_blocks * n_block].reshape(n_blocks, n_block, -1).mean(axis=1)


def block_deviation(means: F64) -> float:
    """Largest absolute deviation of block means (B, k) from their own mean."""
    return float(np.abs(means - means.mean(axis=0)).max())


def block_density(samples: F64, dt_s: float, tau_s: float) -> tuple[float, int]:
    """White-noise density of ``samples`` (N, 3), ``dt_s`` s apart, from the spread of their
    ``tau_s`` block means (averaged over the axes), and its degrees of freedom; (nan, 0) with
    fewer than two blocks."""
    n_block = max(1, round(tau_s / dt_s))
    means = block_means(samples, n_block)
    if len(means) < 2:
        return float("nan"), 0
    var = float(means.var(axis=0, ddof=1).mean())
    return float(np.sqrt(var * n_block * dt_s)), samples.shape[1] * (len(means) - 1)


def measure_static_noise(gyro_B: F64, accel_B: F64, dt_s: float, tau_s: float) -> StaticNoise:
    """Densities of a resting IMU's samples ``gyro_B`` rad/s and ``accel_B`` m/s² (N, 3),
    ``dt_s`` s apart (see the module docstring)."""
    g, dof = block_density(gyro_B, dt_s, tau_s)
    a, _ = block_density(accel_B, dt_s, tau_s)
    return StaticNoise(g, a, float(tau_s), dof)


def rest_deviations(gyro_B: F64, accel_B: F64, n_block: int) -> tuple[float, float]:
    """Largest deviations (accelerometer m/s², gyro rad/s) of the ``n_block``-sample block
    means of ``gyro_B`` and ``accel_B`` (N, 3) from their own means: the rest test's numbers."""
    return (block_deviation(block_means(accel_B, n_block)),
            block_deviation(block_means(gyro_B, n_block)))  # fmt: skip


def rest_window(t_ns: NDArray[np.int64], static_s: float, block_s: float) -> tuple[int, float, int]:
    """The static start's window over IMU stamps ``t_ns`` (N,) ns, increasing: how many of the
    first samples lie within ``static_s`` s of the first, their median spacing (s) and the
    samples per ``block_s`` block."""
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) == 0:
        return 0, 0.0, 1
    n = int(np.searchsorted(t, int(t[0]) + int(static_s * 1e9), side="right"))
    dt_s = max(1e-9, float(np.median(np.diff(t[:n]))) * 1e-9) if n > 1 else 1e-9
    return n, dt_s, max(1, round(block_s / dt_s))


def rest_noise(t_ns: NDArray[np.int64], gyro_S: F64, accel_S: F64, o: InitOptions,
               R_B_S: F64 | None = None) -> StaticNoise | None:  # fmt: skip
    """The white noise of the first ``o.static_s`` s of IMU samples (``t_ns`` (N,) ns, ``gyro_S``
    rad/s and ``accel_S`` m/s² (N, 3), turned to the body by ``R_B_S`` (3, 3) when given) when
    they pass the static start's rest test (block means of ``o.block_s`` within
    ``o.max_accel_dev`` and ``o.max_gyro_dev``), else None."""
    n, dt_s, n_block = rest_window(t_ns, o.static_s, o.block_s)
    if n < 10 or n // n_block < 2:
        return None
    R = np.eye(3) if R_B_S is None else np.asarray(R_B_S, dtype=float)
    gyro_B, accel_B = gyro_S[:n] @ R.T, accel_S[:n] @ R.T
    acc_dev, gyro_dev = rest_deviations(gyro_B, accel_B, n_block)
    if acc_dev > o.max_accel_dev or gyro_dev > o.max_gyro_dev:
        return None
    return measure_static_noise(gyro_B, accel_B, dt_s, o.block_s)


# A rest whose white noise is this many times the calibration's, or this fraction of it, is no
# vibration (EuRoC's MAV with its rotors on: 5.5x gyro, 7.9x accelerometer) but a unit.
UNIT_RATIO_BAND = (0.1, 50.0)
# Above this (and inside the band) the rest may have moved: a tactical IMU on a start with
# micro-motion (a simulated EuRoC V2_02 start, 0.07 m/s² and 0.4°/s of sway) read 18-31x, its
# accuracy halved in silence (a user's probe); EuRoC's vibrating MAV reads 5.5-7.9x.
MOVED_RATIO = 10.0


def platform_noise(
    options: NoiseOptions, calib: ImuCalib | None, measured: StaticNoise | None
) -> tuple[NoiseOptions, dict[str, Any] | None]:
    """``options`` with the densities the rest measured where they exceed the calibration
    significantly (see the module docstring), and what was decided (None: nothing measured,
    no calibration or the rule is off). A density given explicitly in ``options`` is kept."""
    if measured is None or calib is None or not options.static_rule or measured.dof < 1:
        return options, None
    limit = float(np.sqrt(chi2.ppf(options.static_probability, measured.dof) / measured.dof))
    out = options
    info: dict[str, Any] = {"measured": measured.as_dict(), "ratio_limit": limit}
    for name, meas, base, base_walk in (
        ("gyro", measured.gyro_density, calib.gyro_noise_density, calib.gyro_random_walk),
        ("accel", measured.accel_density, calib.accel_noise_density, calib.accel_random_walk),
    ):
        ratio = meas / base if base > 0 and np.isfinite(meas) else 1.0
        explicit = getattr(options, f"{name}_noise_density") is not None
        applied = ratio > limit and not explicit
        info[name] = {"ratio": ratio, "applied": bool(applied)}
        lo, hi = UNIT_RATIO_BAND
        if not explicit and not lo <= ratio <= hi:
            # a density in another unit (per sample, deg, mg) passed in silence, the filter
            # 1000x too sure or too cautious (a user's probe)
            log.warning("the %s's white noise measured at rest is %.3g times its calibrated "
                        "density %.3g: is the calibration's density in another unit (it is "
                        "per √Hz, in rad/s or m/s²)? %s",
                        "accelerometer" if name == "accel" else name, ratio, base,
                        "The measured one is used, and the random walk scaled by the ratio's "
                        "square root" if applied else "The calibration is kept")  # fmt: skip
        elif applied and ratio > MOVED_RATIO:
            log.warning("the %s's white noise measured at rest is %.3g times its calibrated "
                        "density: strong vibration, or a start that was not quite at rest (a "
                        "sway read as noise)? The measured one is used, the filter more "
                        "cautious; --set noise.static_rule=false keeps the calibration",
                        "accelerometer" if name == "accel" else name, ratio)  # fmt: skip
        if not applied:
            continue
        walk = getattr(options, f"{name}_random_walk")
        walk = (base_walk if walk is None else walk) * float(np.sqrt(ratio))
        out = replace(out, **{f"{name}_noise_density": meas, f"{name}_random_walk": walk})
        info[name].update(noise_density=meas, random_walk=walk)
        log.info("%s white noise %.3g measured at rest, %.1fx the calibration: used, random "
                 "walk %.3g", name, meas, ratio, walk)  # fmt: skip
    return out, info
