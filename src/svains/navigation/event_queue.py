"""``EventQueue``: measurements waiting for the IMU clock, released in time order.

Sorted by (t_ns, kind rank, arrival). The owner releases everything stamped before a horizon
(the newest IMU stamp minus the reordering window); a measurement stamped before the horizon
already released is late: dropped, counted per stream and warned about (rate-limited), never
processed out of order.
"""

from __future__ import annotations

import heapq
import logging
from typing import Any

from svains.errors import ConfigError

log = logging.getLogger(__name__)

# Tie order of measurements stamped at the same time (the paper's runner order).
GPS, MAG, SONAR, FRAME, TICK = range(5)
KIND_NAMES = {GPS: "gps", MAG: "mag", SONAR: "sonar", FRAME: "frame", TICK: "tick"}


class EventQueue:
    """Pending ``(t_ns, kind, seq, payload)`` items; ``horizon_ns``: everything stamped before
    it has been released."""

    def __init__(self, max_pending: int) -> None:
        if max_pending < 1:
            raise ConfigError(f"buffer.max_pending must be >= 1, got {max_pending}")
        self.max_pending = max_pending
        self.horizon_ns: int | None = None
        self.dropped: dict[str, int] = {}
        self.late: dict[str, int] = {}  # of the dropped: those that came after their time
        self._heap: list[tuple[int, int, int, Any]] = []
        self._seq = 0

    def __len__(self) -> int:
        return len(self._heap)

    def drop(self, stream: str, t_ns: int, why: str) -> None:
        """Count (and warn about the first few of) a measurement that will not be used."""
        n = self.dropped.get(stream, 0) + 1
        self.dropped[stream] = n
        if n <= 3 or n in (10, 100, 1000):
            log.warning("%s measurement at %d ns dropped (%s; %d so far)", stream, t_ns, why, n)

    def push(self, t_ns: int, kind: int, payload: Any) -> bool:
        """Queue a measurement; False (dropped, counted) if it is late or the queue is full."""
        name = KIND_NAMES[kind]
        if self.horizon_ns is not None and t_ns < self.horizon_ns:
            self.late[name] = self.late.get(name, 0) + 1
            late_ms = (self.horizon_ns - t_ns) * 1e-6
            self.drop(name, t_ns, f"late: stamped {late_ms:.0f} ms before what was already "
                      "processed, beyond buffer.window_s behind the newest IMU sample (add "
                      "that much to the window to keep it)")  # fmt: skip
            return False
        if len(self._heap) >= self.max_pending:
            self.drop(name, t_ns, f"{self.max_pending} measurements already wait for the IMU")
            return False
        heapq.heappush(self._heap, (int(t_ns), kind, self._seq, payload))
        self._seq += 1
        return True

    def pending_after(self, t_ns: int) -> list[tuple[int, str]]:
        """``(t_ns, stream)`` of the waiting measurements stamped after ``t_ns``."""
        return [(t, KIND_NAMES[kind]) for t, kind, _, _ in self._heap if t > t_ns]

    def release(self, horizon_ns: int) -> list[tuple[int, int, Any]]:
        """``(t_ns, kind, payload)`` of every item stamped before ``horizon_ns``, in order."""
        out = []
        while self._heap and self._heap[0][0] < horizon_ns:
            t, kind, _, payload = heapq.heappop(self._heap)
            out.append((t, kind, payload))
        if self.horizon_ns is None or horizon_ns > self.horizon_ns:
            self.horizon_ns = horizon_ns
        return out
