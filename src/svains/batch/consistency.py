"""Monte Carlo consistency test: the NEES averaged over N runs against its χ² bounds.

For a consistent filter the NEES of one state (``dof`` = 9: position, velocity, attitude) is
χ²(dof); the average over N independent runs is χ²(N·dof)/N, whose two-sided 95 % interval is
``[χ²⁻¹(0.025; N·dof), χ²⁻¹(0.975; N·dof)] / N`` (Bar-Shalom, Li, Kirubarajan, *Estimation with
Applications to Tracking and Navigation*, 2001, sec. 5.4.2). It is tested at every logged time
step (about 95 % of the steps should fall inside) and overall, on the average over the runs and
the K steps. Overall, two intervals are given: for N·dof degrees of freedom (conservative: an
average over correlated steps varies no more than one step) and for N·K·dof (exact only if the
steps were independent; they are not, so it is too narrow).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

NEES_DOF = 9


def chi2_average_bounds(
    n_runs: int, dof: int = NEES_DOF, level: float = 0.95
) -> tuple[float, float]:
    """Two-sided ``level`` interval of the average of ``n_runs`` χ²(``dof``) variables."""
    tail = (1.0 - level) / 2.0
    lo, hi = chi2.ppf([tail, 1.0 - tail], n_runs * dof)
    return float(lo / n_runs), float(hi / n_runs)


@dataclass(frozen=True)
class NeesTest:
    """Average NEES of N runs at their K common time steps ``t_ns`` (K,): ``nees_avg`` (K,),
    the per-step 95 % interval ``bounds``, the share of steps inside it, the overall average
    and its two intervals (see the module docstring)."""

    n_runs: int
    t_ns: NDArray[np.int64]
    nees_avg: NDArray[np.float64]
    bounds: tuple[float, float]
    fraction_inside: float
    overall: float
    overall_bounds_runs: tuple[float, float]
    overall_bounds_steps: tuple[float, float]

    @property
    def verdict(self) -> str:
        """``inside``, or by how much the overall average misses the conservative interval."""
        lo, hi = self.overall_bounds_runs
        if self.overall > hi:
            return f"above by {self.overall / hi:.2f}x (overconfident)"
        if self.overall < lo:
            return f"below by {lo / self.overall:.2f}x (too cautious)"
        return "inside"


def nees_test(series: list[tuple[NDArray[np.int64], NDArray[np.float64]]]) -> NeesTest | None:
    """The test on per-run ``(t_ns, nees)`` series, at the time steps every run has; ``None``
    for no run or no common step."""
    if not series:
        return None
    common = series[0][0]
    for t, _ in series[1:]:
        common = np.intersect1d(common, t)
    if len(common) == 0:
        return None
    stack = np.stack([v[np.searchsorted(t, common)] for t, v in series])  # (N, K)
    n, k = stack.shape
    avg = stack.mean(axis=0)
    lo, hi = chi2_average_bounds(n)
    return NeesTest(
        n_runs=n, t_ns=common, nees_avg=avg, bounds=(lo, hi),
        fraction_inside=float(np.mean((avg >= lo) & (avg <= hi))), overall=float(stack.mean()),
        overall_bounds_runs=(lo, hi), overall_bounds_steps=chi2_average_bounds(n * k),
    )  # fmt: skip
