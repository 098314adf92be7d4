"""Extension point for vision updaters (``tc``, ``3d``, ``lc``) inside the ``Navigator``.

How it works (``navigation.navigator_core.Core``):

1. The Navigator builds the updater of ``config.method`` once the first stereo frame arrives
   (``vision.make_vision_updater(method, options, source, history, rig)``); it follows
   :class:`VisionUpdater`. Its tracks come from the frame's source (pre-tracked features or the
   image front end, ``vision_sources``).
2. For each vision frame (in time order with the GPS, magnetometer, sonar and output ticks) the
   Navigator propagates the filter with the IMU **exactly to the frame time** (the IMU sample at
   the frame time is linearly interpolated between its neighbours), first fuses the non-vision
   measurements stamped at that time (one ``UKF.update_blocks`` call, each gated on its own)
   unless ``FilterOptions.stack_with_vision`` is True, and then calls ``updater.update(ctx)``.
3. ``ctx`` (:class:`FrameContext`) gives the updater the filter (state ``ukf.x`` (nx,), tangent
   covariance ``ukf.P`` (ndx, ndx), both at ``t_ns``), the state layout (``svains.models.state``
   slices ``P, V, Q, W, BG, BA``), the previous frame time ``t_prev_ns`` (``None`` at the first
   frame) and, when ``stack_with_vision`` is True, ``extra`` = the non-vision measurement blocks
   stamped at this very time, to be stacked with the vision block in ONE update.
4. A vision update is one call ``ctx.apply([block, *ctx.extra])`` (or ``ctx.ukf.update(...)``
   directly) where ``block = MeasurementBlock(name, h, z, R)`` and ``h(X (S, nx)) -> (S, nz)`` is
   vectorised over the sigma points (e.g. 4 pixel numbers per feature, hundreds of features).
   ``apply`` returns :class:`svains.filter.ukf.UpdateStats` (accepted/rejected by the chi-square
   gate, NIS, dimension); the updater returns it (or ``None`` when the frame gave nothing to fuse,
   e.g. no tracks) so the Navigator counts fused and rejected frames under the method's name.

Filter API an updater may use: ``ukf.x``, ``ukf.P``, ``ukf.sigma_points() -> (X (S, nx),
offsets (S, ndx))``, ``ukf.points`` (weights ``Wm``, ``Wc``), ``ukf.update(h, z, R,
gate_probability, residual, name)``; layout slices in ``svains.models.state``; the manifold
(box-plus/minus) in ``svains.models.manifold.NavManifold``.

Pure VO needs no filter: it runs in the replay (``svains.replay.vo``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import UKF, UpdateStats
from svains.models.state import StateLayout

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def find_ids(keys: I64, ids: I64) -> tuple[NDArray[np.bool_], I64]:
    """Where the track ids ``ids`` (M,) sit in the unique, unsorted ``keys`` (K,): whether
    each is there (M,), and its index in ``keys`` (M,; meaningless where it is not)."""
    if keys.size == 0:
        return np.zeros(ids.shape, bool), np.zeros(ids.shape, np.int64)
    order = np.argsort(keys, kind="stable")
    pos = np.clip(np.searchsorted(keys[order], ids), 0, keys.size - 1)
    index = order[pos]
    return keys[index] == ids, index


@dataclass(frozen=True)
class MeasurementBlock:
    """One measurement for a (possibly stacked) UKF update.

    ``h(X (S, nx)) -> (S, nz)`` vectorised over sigma points; ``z`` (nz,); ``R`` (nz, nz) or its
    diagonal (nz,); ``residual(a (..., nz), b (nz,)) -> (..., nz)`` for angle-like components
    (``None`` = plain subtraction).
    """

    name: str
    h: Callable[[F64], F64]
    z: F64
    R: F64
    residual: Callable[[F64, F64], F64] | None = None


@dataclass
class FrameContext:
    """What a vision updater sees at one frame time ``t_ns`` (filter already propagated there)."""

    ukf: UKF
    layout: StateLayout
    t_ns: int
    t_prev_ns: int | None
    gate_probability: float | None
    extra: list[MeasurementBlock] = field(default_factory=list)
    apply: Callable[[Sequence[MeasurementBlock]], UpdateStats] = field(repr=False, default=None)  # type: ignore[assignment]
    # tc/3d: marginalise each point over both frames for this frame (``vision.two_view``), set by
    # the Core while the prediction rests on an IMU gap's bridge (``faults.gap_vision_two_view``)
    two_view: bool = False


@runtime_checkable
class VisionUpdater(Protocol):
    """A vision method plugged into the Navigator (see the module docstring)."""

    method: str

    def update(self, ctx: FrameContext) -> UpdateStats | None:
        """Fuse the frame at ``ctx.t_ns``; return the update's stats, ``None`` if nothing fused."""
        ...
