"""The zero-velocity updates' options (``RunConfig.zupt``; ``navigation.zupt``)."""

from __future__ import annotations

from dataclasses import dataclass

from svains.errors import ConfigError
from svains.navigation.option_types import check_types


@dataclass(frozen=True)
class ZuptOptions:
    """Zero-velocity updates while the platform rests (``navigation.zupt``): every
    ``period_s`` the IMU of the last ``window_s`` is tested (block means within the static
    start's limits, ``InitOptions``); at rest ``v_W_B = 0`` is fused with ``velocity_std_mps``
    per axis, gated like GPS (``filter.gate_probability``).

    Every rest the vision methods' camera witnesses (``after_start`` None, the default, or
    true): after the start's rest the camera is a second witness, the speed its features allow
    over the last ``window_s`` (``navigation.still_camera``: the fitted motion plus 3 standard
    deviations) must stay under ``still_max_speed_mps``, and the zero velocity is then fused
    with that bound as its standard deviation when larger than ``velocity_std_mps``. ``ins``
    has only the start's rest by default: in flight a smooth motion passes the IMU test too
    (EuRoC V1_01 at 0.3 m/s: block means as steady as at rest; the simulated village flight
    passes it about 190 times a minute) and the gate, with frames 2 s apart, let two such
    updates through and the filter diverged; ``after_start`` true gives ``ins`` the IMU's
    test alone (warned). ``after_start`` false: the start's rest only, for every method.
    The camera also ends the start's rest where the IMU's limits pass a creep
    (``start_camera``).
    """

    enabled: bool = True
    after_start: bool | None = None  # None: the vision methods' stops too, not ins'
    limit_factor: float = 2.0  # times the static start's block-mean limits (``InitOptions``)
    window_s: float = 0.5
    period_s: float = 0.1
    # At rest the body moves only with the vibration: 0.3 m/s² at >= 30 Hz is < 2 mm/s. EuRoC
    # static drift over 4.6 s (``bench/euroc_static_drift.py``): 4.67 / 4.49 / 2.89 mm with
    # 0.05 / 0.01 / 0.002 m/s.
    velocity_std_mps: float = 0.002
    # The start's rest also ends once the specific force since the start, less its static mean,
    # integrates past motion_sigmas x its block means' spread x sqrt(block x elapsed), and at
    # least motion_floor_mps (a gentle start passes the block test; ``zupt.StaticTest``).
    motion_sigmas: float = 4.0  # the gained velocity's limit, in its noise's std
    motion_floor_mps: float = 0.05  # m/s, the limit's floor
    # the camera's witness (``after_start``, vision methods): the speed bound (m/s) under which
    # a rest the IMU passed is fused
    still_max_speed_mps: float = 0.05
    # the vision methods' camera may end the START's rest, where the IMU's limits pass a creep
    # (``StillCamera.start_rest_std``; needs the camera's witness, ``after_start``)
    start_camera: bool = True

    def after_start_for(self, method: str) -> bool:
        """Whether ``method``'s rests after the start's are tested (``after_start``; None:
        the vision methods', which have the camera as a second witness)."""
        return method != "ins" if self.after_start is None else self.after_start

    def __post_init__(self) -> None:
        check_types(self, "zupt.")
        for name in ("window_s", "period_s", "velocity_std_mps", "limit_factor",
                     "motion_sigmas", "motion_floor_mps", "still_max_speed_mps"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"zupt.{name} must be positive, got {getattr(self, name)}")
