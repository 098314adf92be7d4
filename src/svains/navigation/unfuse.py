"""Take back the updates of a sensor found leaning (``ConsistencyMonitor.leaning``).

A magnetometer turned by steel nearby passes its gate sample by sample; the lean test sees it
after its window (5 samples) and holds the sensor, but the samples already fused stay in the
state. On the simulator's fault bench (8° for 10 s from 10 s) they are what `3d` loses: with
the samples of 10.0-20.3 s simply absent it ends at 1.00x its clean position RMSE; held after
the lean test, 1.72x. Five samples tilt the pose by a few tenths of a degree and, through its
correlations, move the position by about 5 cm, which 1 Hz GPS fixes of 1.4 m never pull back.

Each accepted update of a watched sensor leaves its share of the joint update
(``UpdateStats.contribution``: the correction and covariance decrease with it minus without
it, ``UKF.update_blocks(contribution_of=...)``), kept with the times of the pose clones the
state held then. Un-fusing subtracts the shares' corrections and adds their covariance
decrease back to the navigation block. A clone gets back what the sample did to it; a clone
made after the sample (a copy of the pose by then) gets the pose's share instead: the same
sample moved the pose by 0.4° and the clone of 0.5 s before by 0.03° (the images had pinned
the clone; the pose's recent turn was what the magnetometer could move). First-order: exact
for a linear model without process noise between the samples and the undo
(``tests/test_unfuse.py``). A smoother (``--smooth``) takes the change as it takes an update:
its backward pass crosses it (``UKF.set_posterior``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import UKF, UpdateStats
from svains.models.clones import CLONE_NDX, CloneManifold
from svains.models.state import DP, DTH

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Share:
    """One update's share: ``dx`` (ndx,) and ``dP`` (ndx, ndx) in the tangent of the state it
    updated, whose pose clones were those of ``clone_times`` (ns, in state order)."""

    dx: F64
    dP: F64
    clone_times: tuple[int, ...]


class LeanShares:
    """The last ``window`` accepted shares of each watched sensor (the lean test's window:
    ``ConsistencyOptions.lean_window``)."""

    def __init__(self, sensors: tuple[str, ...], window: int) -> None:
        self._shares: dict[str, deque[Share]] = {name: deque(maxlen=window) for name in sensors}

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self._shares)

    def observe(self, stats: UpdateStats, clone_times: tuple[int, ...]) -> None:
        """Keep ``stats``' share when it is an accepted update of a watched sensor."""
        shares = self._shares.get(stats.name)
        if shares is None or not stats.accepted or stats.contribution is None:
            return
        dx, dP = stats.contribution
        shares.append(Share(dx, dP, tuple(clone_times)))

    def take(self, sensor: str) -> list[Share]:
        """The kept shares of ``sensor``, forgotten."""
        shares = self._shares.get(sensor)
        if shares is None:
            return []
        out = list(shares)
        shares.clear()
        return out


def unfuse(ukf: UKF, shares: list[Share], clone_times: tuple[int, ...] = ()) -> F64:
    """Subtract ``shares`` from ``ukf`` (see the module docstring); ``clone_times`` (ns) of the
    state's pose clones now, in state order. Returns the tangent correction applied (ndx,)."""
    m = ukf.manifold
    clones = m.n_clones if isinstance(m, CloneManifold) else 0
    k = m.nav.ndx if isinstance(m, CloneManifold) else m.ndx
    d = np.zeros(m.ndx)
    dP = np.zeros((k, k))
    for s in shares:
        d[:k] -= s.dx[:k]  # the navigation block leads every tangent vector
        dP += s.dP[:k, :k]
        for i in range(clones):
            t = m.tangent(i)  # type: ignore[union-attr]
            if i < len(clone_times) and clone_times[i] in s.clone_times:
                j = s.clone_times.index(clone_times[i])
            elif s.clone_times:
                j = len(s.clone_times) - 1  # made since: what the sample left in the latest
            else:
                d[t.start : t.start + 3] -= s.dx[DP]
                d[t.start + 3 : t.start + 6] -= s.dx[DTH]
                continue
            a = s.dx.size - CLONE_NDX * (len(s.clone_times) - j)  # clones close the vector
            d[t] -= s.dx[a : a + CLONE_NDX]
    x = m.retract(ukf.x[None, :], d[None, :])[0]
    P = ukf.P.copy()
    P[:k, :k] += dP
    # an instant's change, as an update is: a smoother bridges it (it was a cut: the smoothed
    # trajectory stepped 15 cm there and the 40 s before lost most of their smoothing, on a
    # clean flight's false alarm: a user's probe)
    ukf.set_posterior(x, P)
    return d
