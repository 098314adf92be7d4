"""Report keys that say when a vision method ran without vision ("never silently degraded").

:func:`vision_gap_report` turns the times of the fused vision updates and the run's span into the
``report.json`` keys below; the runner warns when ``vision_gaps`` is not empty, and a run that
asked for vision and fused none (``vision_degraded``) exits non-zero unless ``--allow-degraded``.

- ``vision_gaps``: list of ``{start_s, duration_s}`` (from the run's start) without a fused
  vision update for more than ``max_gap_s``, the run's start and end included;
- ``vision_longest_gap_s``: the longest stretch without a fused vision update (s);
- ``vision_gap_fraction``: fraction of the run's span inside ``vision_gaps``;
- ``vision_fused_frames``: number of fused vision updates;
- ``vision_degraded``: vision was asked for and none was fused.
"""

from __future__ import annotations

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
    }
