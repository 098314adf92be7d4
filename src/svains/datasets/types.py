"""In-memory types every reader and the simulator produce (the contract between packages).

All timestamps are int64 nanoseconds (``t_ns``); arrays are float64 SI unless named otherwise.
Frames follow ``docs/conventions.md``: ``T_B_S`` is sensor-to-body (EuRoC's ``T_BS``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from svains.sensors.types import (
    CameraCalib,
    GpsCalib,
    GroundTruth,
    ImuCalib,
    MagCalib,
    SonarCalib,
)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

DEFAULT_GRAVITY_W = (0.0, 0.0, -9.81)
# Left/right frames this close are one stereo pair (``datasets.stereo_sync``); ``body.yaml``
# ``stereo_pair_tolerance_ns`` overrides it per data set.
DEFAULT_STEREO_TOL_NS = 10_000_000

__all__ = [
    "CameraCalib", "Dataset", "FeatureStream", "GpsCalib", "GpsStream", "GroundTruth",
    "ImageStream", "ImuCalib", "ImuStream", "MagCalib", "MagStream", "SonarCalib",
    "SonarStream",
]  # fmt: skip


@dataclass(frozen=True)
class ImuStream:
    """IMU samples: ``gyro_B`` (N, 3) rad/s and ``accel_B`` (N, 3) specific force m/s², as the
    file holds them: in the IMU's own frame S, which ``ImuCalib.T_B_S`` turns to the body (the
    identity on EuRoC and the simulator). ``Navigator.feed_imu`` takes them as they are."""

    t_ns: I64
    gyro_B: F64
    accel_B: F64


@dataclass(frozen=True)
class ImageStream:
    """Image timestamps and files; images are decoded on demand by ``load(i)`` (uint8 grey)."""

    t_ns: I64
    paths: tuple[Path, ...]
    loader: Callable[[Path], NDArray[np.uint8]] = field(repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.t_ns)

    def load(self, i: int) -> NDArray[np.uint8]:
        return self.loader(self.paths[i])

    def rows(self, keep: NDArray[np.bool_]) -> ImageStream:
        """The images where ``keep`` (N,) is True, decoded by the same loader."""
        idx = np.flatnonzero(keep)
        return replace(self, t_ns=self.t_ns[idx], paths=tuple(self.paths[i] for i in idx))


@dataclass(frozen=True)
class GpsStream:
    """Antenna position ``p_W_G`` (N, 3) m and velocity ``v_W_G`` (N, 3) m/s, local world frame;
    a fix without velocity (a receiver that gives position only) has a NaN row in ``v_W_G``."""

    t_ns: I64
    p_W_G: F64
    v_W_G: F64

    @property
    def has_velocity(self) -> NDArray[np.bool_]:
        """(N,) whether each fix carries a velocity."""
        return np.all(np.isfinite(self.v_W_G), axis=1)

    def position_only(self) -> GpsStream:
        """The same fixes without their velocities (as a ROS ``NavSatFix`` gives them)."""
        return replace(self, v_W_G=np.full_like(self.v_W_G, np.nan))

    def velocity_or_differenced(self) -> F64:
        """(N, 3) m/s: the fixes' velocities, or where a fix has none the positions' central
        difference (one-sided at the ends) for checks that only need the course and speed."""
        v = self.v_W_G.copy()
        missing = ~self.has_velocity
        if missing.any() and len(self.t_ns) > 1:
            t_s = (self.t_ns - self.t_ns[0]) * 1e-9
            v[missing] = np.gradient(self.p_W_G, t_s, axis=0)[missing]
        return v


@dataclass(frozen=True)
class MagStream:
    """Measured field ``m_S`` (N, 3) Gauss in the sensor frame."""

    t_ns: I64
    m_S: F64


@dataclass(frozen=True)
class SonarStream:
    """Ranges ``range_m`` (N,) along the sensor's +z axis to flat ground."""

    t_ns: I64
    range_m: F64


@dataclass(frozen=True)
class FeatureStream:
    """Stereo feature observations, one row per (frame, track), rows sorted by ``t_ns``.

    ``track_id`` (M,) int64; ``uv_left``, ``uv_right`` (M, 2) px in the rectified pair.
    """

    t_ns: I64
    track_id: I64
    uv_left: F64
    uv_right: F64
    pixel_noise_std: float

    def frame_times(self) -> I64:
        """Distinct frame timestamps (F,) in increasing order."""
        return np.unique(self.t_ns)


class _Deferred:
    """A stream's reader, called on first access (see ``LazyStream``)."""

    __slots__ = ("read",)

    def __init__(self, read: Callable[[], object]) -> None:
        self.read = read


class LazyStream:
    """Descriptor of a ``Dataset`` stream its reader may defer (``Dataset.defer``): read on first
    access, then kept. Set and read like a plain attribute otherwise; the default is ``None``.

    Why: a data set's simulated ``features0`` (370k rows for 20 s at 20 Hz) takes seconds to
    parse, and a run from images never reads it.
    """

    def __set_name__(self, owner: type, name: str) -> None:
        self._slot = f"_{name}_stream"

    def __get__(self, obj: object, objtype: type | None = None) -> object:
        if obj is None:
            return None  # the dataclass default
        value = obj.__dict__.get(self._slot)
        if isinstance(value, _Deferred):
            value = value.read()
            obj.__dict__[self._slot] = value
        return value

    def __set__(self, obj: object, value: object) -> None:
        obj.__dict__[self._slot] = value

    def present(self, obj: object) -> bool:
        """True if ``obj`` holds this stream or a deferred reader of it (nothing is read)."""
        return obj.__dict__.get(self._slot) is not None


@dataclass
class Dataset:
    """Everything one data set holds; any stream may be ``None``.

    ``gravity_W`` (3,) m/s² comes from ``body.yaml`` (default EuRoC z-up), as may
    ``stereo_tol_ns`` (largest left/right stamp difference of one stereo pair). ``features`` may
    be deferred by the reader: it is parsed on first access; ``has_stream`` tells whether it is
    there without reading it.
    """

    root: Path
    name: str
    gravity_W: F64 = field(default_factory=lambda: np.array(DEFAULT_GRAVITY_W))
    stereo_tol_ns: int = DEFAULT_STEREO_TOL_NS
    imu: ImuStream | None = None
    imu_calib: ImuCalib | None = None
    cam0: CameraCalib | None = None
    cam1: CameraCalib | None = None
    left: ImageStream | None = None
    right: ImageStream | None = None
    groundtruth: GroundTruth | None = None
    gps: GpsStream | None = None
    gps_calib: GpsCalib | None = None
    mag: MagStream | None = None
    mag_calib: MagCalib | None = None
    sonar: SonarStream | None = None
    sonar_calib: SonarCalib | None = None
    features: FeatureStream | None = LazyStream()  # type: ignore[assignment]
    missing_images: dict[str, int] = field(default_factory=dict)
    extras: dict[str, object] = field(default_factory=dict)

    def defer(self, name: str, read: Callable[[], object]) -> None:
        """Let stream ``name`` (a ``LazyStream`` attribute) be read by ``read()`` on first use."""
        if not isinstance(type(self).__dict__.get(name), LazyStream):
            raise ValueError(f"stream '{name}' cannot be deferred")
        setattr(self, name, _Deferred(read))

    def has_stream(self, name: str) -> bool:
        """True if stream ``name`` (a ``Dataset`` attribute) is present, without reading it."""
        desc = type(self).__dict__.get(name)
        if isinstance(desc, LazyStream):
            return desc.present(self)
        return getattr(self, name) is not None
