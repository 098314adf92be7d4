"""Report keys that say when a vision method ran without vision ("never silently degraded").

:func:`vision_gap_report` turns the times of the fused vision updates and the run's span into the
``report.json`` keys below; the runner warns when ``vision_gaps`` is not empty, and a run that
asked for vision and fused none (``vision_degraded``) exits non-zero unless ``--allow-degraded``.

- ``vision_gaps``: list of ``{start_s, duration_s}`` (from the run's start) without a fused
  vision update for more than ``max_gap_s``, the run's start and end included (the Navigator
  gives the warning's limit: ``faults.vision_max_gap_s``, or 2.5 frame spacings where frames
  come further apart);
- ``vision_gap_limit_s``: that ``max_gap_s``;
- ``vision_longest_gap_s``: the longest stretch without a fused vision update (s);
- ``vision_gap_fraction``: fraction of the run's span inside ``vision_gaps``;
- ``vision_fused_frames``: number of fused vision updates;
- ``vision_degraded``: vision was asked for and none was fused.

:class:`FramesSinceFused` says, with the warning, what became of the frames since the last fused
one.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

DEFAULT_MAX_GAP_S = 2.0  # s, a configurable default: several frames at any usual camera rate
# A stretch without fused vision is warned past this many of the stream's longer frame
# spacings: their GAP_SPACING_PERCENTILE-th percentile, so frames that alternate between 0.2 s
# and 5 s apart count 5 s as usual, not whichever of the two the median lands on (a user's
# probe: no warning for 83 s, then one at every 5 s spacing).
VISION_GAP_SPACINGS = 2.5
GAP_SPACING_PERCENTILE = 80.0


def vision_gap_limit_s(spacings_ns: ArrayLike, floor_s: float = DEFAULT_MAX_GAP_S) -> float:
    """The longest stretch (s) without fused vision that is not warned: ``floor_s``, or
    ``VISION_GAP_SPACINGS`` of the recent frame spacings ``spacings_ns`` (ns) where frames come
    further apart."""
    dt = np.asarray(spacings_ns, dtype=float)
    if dt.size == 0:
        return float(floor_s)
    usual = float(np.percentile(dt, GAP_SPACING_PERCENTILE)) * 1e-9
    return max(float(floor_s), VISION_GAP_SPACINGS * usual)


def vision_gap_report(
    fused_t_ns: ArrayLike, t_start_ns: int, t_end_ns: int, max_gap_s: float = DEFAULT_MAX_GAP_S
) -> dict[str, Any]:
    """Gaps longer than ``max_gap_s`` between fused vision updates (times ``fused_t_ns`` (F,)
    int64 ns) over the run ``[t_start_ns, t_end_ns]``; keys in the module docstring."""
    if t_end_ns < t_start_ns:
        raise ValueError(f"run ends ({t_end_ns}) before it starts ({t_start_ns})")
    t = np.asarray(fused_t_ns, dtype=np.int64)
    t = np.unique(t[(t >= t_start_ns) & (t <= t_end_ns)])
    edges = np.concatenate([[t_start_ns], t, [t_end_ns]]).astype(np.int64)
    starts, lengths = edges[:-1], np.diff(edges)
    span_ns = t_end_ns - t_start_ns
    long = lengths > int(max_gap_s * 1e9)
    gaps = [
        {"start_s": (int(s) - t_start_ns) / 1e9, "duration_s": int(d) / 1e9}
        for s, d in zip(starts[long], lengths[long], strict=True)
    ]
    return {
        "vision_gaps": gaps,
        "vision_longest_gap_s": int(lengths.max()) / 1e9 if lengths.size else 0.0,
        "vision_gap_fraction": float(lengths[long].sum()) / span_ns if span_ns > 0 else 0.0,
        "vision_fused_frames": int(t.size),
        "vision_degraded": bool(t.size == 0),
        "vision_gap_limit_s": float(max_gap_s),
    }


# The front end's per-frame statuses as the vision gap's warning says them.
_STATUS_WORDS = {"first": "first frame", "contradicts_prior": "contradicting the IMU"}


@dataclass
class FramesSinceFused:
    """The filter's outcome of each frame since the last fused one, and, at that one, the front
    end's status counts and the count of frames dropped before the filter (a user's probe:
    keyframes seconds apart on a car matched nothing, and only "no vision fused for 13.8 s" was
    said)."""

    outcomes: Counter[str] = field(default_factory=Counter)
    status_at_fused: dict[str, int] = field(default_factory=dict)
    dropped_at_fused: int = 0

    def fused(self, status_counts: dict[str, int], dropped: int) -> None:
        """A frame fused; ``status_counts`` and ``dropped``: the totals so far."""
        self.outcomes.clear()
        self.status_at_fused, self.dropped_at_fused = dict(status_counts), dropped

    def not_fused(self, refused: bool) -> None:
        """A frame refused by the filter, or (``refused`` false) without an update."""
        self.outcomes["refused by the filter" if refused else "without an update"] += 1

    def reasons(self, status_counts: dict[str, int], dropped: int) -> str:
        """`` (N frames since; ...)`` for the warning, from the totals so far."""
        since = Counter(self.outcomes)
        if dropped > self.dropped_at_fused:
            since["dropped before the filter (see the warnings above)"] = (
                dropped - self.dropped_at_fused)
        parts = [f"{n} {what}" for what, n in sorted(since.items())]
        front = {k: v - self.status_at_fused.get(k, 0) for k, v in status_counts.items()}
        said = [f"{v} {_STATUS_WORDS.get(k, k.replace('_', ' '))}"
                for k, v in sorted(front.items()) if v > 0 and k != "ok"]  # fmt: skip
        if said:
            parts.append("front end: " + ", ".join(said))
        n = sum(since.values())
        return f" ({n} frame{'s' if n != 1 else ''} since; {'; '.join(parts)})" if n else \
            " (no frame since)"

