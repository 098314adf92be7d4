"""The pose clones a vision updater keeps in the filter's state (``rotation="clone"``).

``CloneWindow`` augments the UKF's state with a copy of the body pose at a frame time
(``models.clones``) and marginalises the clones no later frame will be measured against. Keyed
by the frame time the filter was propagated to. One frame's cycle:

1. the updater asks ``columns(ukf, tracks.t_prev_ns)`` for the clone of the tracks' reference
   frame (None: no clone, e.g. the first frame after the start: the frame is skipped);
2. it fuses with the exact relative-motion models of ``models.vision_clone``;
3. ``after_frame(ukf, t_ns, reference_ns)`` (once per frame, fused or not) clones the pose at
   ``t_ns`` if the next tracks will start there, and drops every clone but the reference's.

The front end may hold its reference frame (a frame it could not track keeps the older one):
``reference_ns`` is then older than ``t_ns`` and its clone stays. At most one clone is kept, so
the biased UKF has 49 sigma points instead of 37.
"""

from __future__ import annotations

import numpy as np

from svains.filter.ukf import UKF
from svains.models.clones import CloneManifold, augment_clone, marginalize_clone
from svains.models.manifold import NavManifold


class CloneWindow:
    """Times (ns) of the clones in ``ukf``'s state, in state order."""

    def __init__(self) -> None:
        self.times: list[int] = []

    def columns(self, ukf: UKF, t_ns: int | None) -> tuple[slice, slice] | None:
        """Columns ``(p_W_B, q_W_B_wxyz)`` of the clone at ``t_ns`` in ``ukf.x`` (None: none)."""
        if t_ns is None or int(t_ns) not in self.times:
            return None
        manifold = ukf.manifold
        assert isinstance(manifold, CloneManifold)
        return manifold.columns(self.times.index(int(t_ns)))

    def after_frame(self, ukf: UKF, t_ns: int, reference_ns: int | None) -> None:
        """Clone the pose at ``t_ns`` when it is the next tracks' reference; drop the others."""
        manifold = ukf.manifold
        if not isinstance(manifold, CloneManifold):
            assert isinstance(manifold, NavManifold)
            manifold = CloneManifold(manifold, 0)
        x, P = ukf.x, ukf.P
        times = list(self.times)
        if reference_ns is not None and int(reference_ns) == int(t_ns) and t_ns not in times:
            x, P, manifold = augment_clone(x, P, manifold)
            times.append(int(t_ns))
        for i in reversed(range(len(times))):
            if reference_ns is None or times[i] != int(reference_ns):
                x, P, manifold = marginalize_clone(x, P, manifold, i)
                del times[i]
        if times != self.times or manifold is not ukf.manifold:
            ukf.resize(manifold, x, np.asarray(P))
        self.times = times


def next_reference_ns(source: object, t_ns: int) -> int | None:
    """The frame the next tracks will start from: the image front end's reference frame, or
    ``t_ns`` for recorded tracks (always tracked from the previous frame)."""
    ref = getattr(source, "reference_time_ns", None)
    return int(t_ns) if ref is None else ref()
