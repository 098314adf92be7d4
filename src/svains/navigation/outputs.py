"""What the estimator hands out: ``NavState`` snapshots and the whole run's ``RunResult``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from svains.filter.rts import RtsRecorder
from svains.filter.ukf import UpdateStats
from svains.geometry.rotation import quat_to_rotmat
from svains.models.state import BA, BG, P, Q, StateLayout, V, W
from svains.navigation.track_log import TrackLog

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

WorldFrame = Literal["groundtruth", "gps", "local"]


@dataclass(frozen=True)
class NavState:
    """The estimate at ``t_ns`` (int64 ns, the IMU clock).

    ``p_W_B`` (3,) m and ``v_W_B`` (3,) m/s of the body origin in the world frame W (z up,
    gravity ``rig.gravity_W``); ``q_W_B_wxyz`` (4,) body-to-world attitude; ``omega_B`` (3,)
    rad/s body rate; ``bg_B``, ``ba_B`` (3,) gyro (rad/s) and accelerometer (m/s²) biases,
    ``None`` in the paper model (no bias states); ``P`` (ndx, ndx) tangent covariance of
    (δp, δv, δθ, δω[, δbg, δba]) (δθ: body-frame attitude error, rad; see
    ``docs/conventions.md``). ``heading_known`` False: a static start without magnetometer
    still waiting for the GPS to give its heading (``init.heading_from_gps``): the state is
    in the start's local frame, its yaw (and the direction of the motion since) not the
    world's whatever ``P`` says; it turns into the world when the heading is found.
    """

    t_ns: int
    p_W_B: F64
    v_W_B: F64
    q_W_B_wxyz: F64
    omega_B: F64
    bg_B: F64 | None
    ba_B: F64 | None
    P: F64
    heading_known: bool = True

    @property
    def T_W_B(self) -> F64:
        """Body-to-world pose (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = quat_to_rotmat(self.q_W_B_wxyz)
        T[:3, 3] = self.p_W_B
        return T

    @classmethod
    def from_state(cls, t_ns: int, x: F64, P_: F64, layout: StateLayout,
                   heading_known: bool = True) -> NavState:  # fmt: skip
        x = np.array(x, dtype=float)
        return cls(
            int(t_ns), x[P], x[V], x[Q], x[W], x[BG] if layout.biased else None,
            x[BA] if layout.biased else None, np.array(P_, dtype=float), heading_known,
        )  # fmt: skip


@dataclass(frozen=True)
class UpdateRecord:
    """One measurement update at ``t_ns`` (the filter's time): ``sensor`` the key it is counted
    under in ``report["measurements"]`` (``gps``, ``mag``, ``sonar``, the vision method)."""

    t_ns: int
    sensor: str
    stats: UpdateStats


@dataclass(frozen=True)
class FrameTurn:
    """The world frame turned at ``t_ns`` by ``angle_rad`` (standard deviation ``std_rad``)
    about the unit vertical ``up_W`` (3,) through ``pivot_W`` (3,) m."""

    t_ns: int
    angle_rad: float
    std_rad: float
    up_W: F64
    pivot_W: F64


@dataclass
class RunResult:
    """Logged estimates: ``t_ns`` (T,), ``x`` (T, nx), ``std`` (T, ndx) tangent std devs,
    ``P9`` (T, 9, 9) covariance of (p, v, δθ); ``report`` = the ``report.json`` content.

    ``world_frame`` says what ties the estimate's world frame to the ground truth's:
    ``groundtruth`` (initialised from it), ``gps`` (GPS fixes fused) or ``local`` (static start
    without GPS: yaw and position are arbitrary, so raw errors against ground truth mean nothing).
    ``gps_used``: GPS was enabled and present; ``has_covariance``: False for filter-free methods.
    ``updates``: every measurement update's outcome (name, accepted, NIS, dof, gate; their
    arrays, residual to contribution, are not kept: hundreds of MB per hour); ``update_log``:
    the same with its time and sensor (``updates.csv``);
    ``tracks``: the vision tracks of every frame (``tracks.csv``), None without vision.
    ``history``: what a smoother needs (``smoother.enabled``; ``navigation.smoothing``).
    """

    t_ns: I64
    x: F64
    std: F64
    P9: F64
    report: dict[str, Any]
    updates: list[UpdateStats] = field(default_factory=list, repr=False)
    update_log: list[UpdateRecord] = field(default_factory=list, repr=False)
    tracks: TrackLog | None = field(default=None, repr=False)
    world_frame: WorldFrame = "groundtruth"
    gps_used: bool = False
    has_covariance: bool = True
    history: RtsRecorder | None = field(default=None, repr=False)
    # The world frame turned at these times, the estimates logged before each too
    # (``navigation.heading_wait``): a smoother's corrections of those are the old frame's.
    frame_turns: list[FrameTurn] = field(default_factory=list, repr=False)
    # The smoothed estimates (``navigation.smoothing.smoothed_result``), once computed.
    smoothed: RunResult | None = field(default=None, repr=False)
