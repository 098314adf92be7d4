"""The smoother's options (``RunConfig.smoother``; ``navigation.smoothing``)."""

from __future__ import annotations

from dataclasses import dataclass

from svains.errors import ConfigError
from svains.navigation.option_types import check_types


@dataclass(frozen=True)
class SmootherOptions:
    """Forward-backward smoothing of a recorded run (``navigation.smoothing``, ``--smooth``):
    an unscented Rauch-Tung-Striebel pass over the filter's history, for the methods with a
    filter (``ins``, ``lc``, ``tc``, ``3d``).

    The filter records what the backward pass needs as it runs (``filter.rts``): a whole-state
    epoch every ``chain_interval_s`` and, per output state, the (p, v, θ) rows tied to the next
    one; nothing per IMU sample. A longer interval keeps less memory and costs more per update.
    """

    enabled: bool = False  # record the history and write the smoothed outputs too
    chain_interval_s: float = 1.0

    def __post_init__(self) -> None:
        check_types(self, "smoother.")
        if not self.chain_interval_s > 0:
            raise ConfigError(
                f"smoother.chain_interval_s must be positive, got {self.chain_interval_s}"
            )
