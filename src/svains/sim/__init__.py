"""Simulator: the paper's village flight and real-trajectory flights, written as ASL data sets.

Public API: :class:`SimConfig` (nested sensor configs, YAML round trip) and
:func:`simulate` ``(config, out_dir) -> Path``.
"""

from svains.sim.config import SimConfig
from svains.sim.simulate import simulate

__all__ = ["SimConfig", "simulate"]
