"""``bench/height_split.py --reference-velocity``: the reference's own velocity, integrated and
tied to its positions at a window's ends, is the yardstick that tells a reference whose
positions disagree with its velocities (KITTI raw's OXTS height) from an estimator's error."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np

from svains.datasets.types import GroundTruth

BENCH = Path(__file__).resolve().parents[1] / "bench" / "height_split.py"
S = 1_000_000_000


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("height_split", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _reference(step_m: float) -> GroundTruth:
    """A curved 20 s drive sampled irregularly (10-250 ms, as KITTI raw's OXTS records) with
    exact velocities; the positions from 10 s on raised by ``step_m`` (velocities unchanged)."""
    rng = np.random.default_rng(3)
    t_s = np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.25, 400))])
    t_s = t_s[t_s <= 20.0]
    p = np.stack([8 * np.sin(0.3 * t_s), 0.2 * t_s**2, 0.05 * t_s], axis=1)
    v = np.stack([2.4 * np.cos(0.3 * t_s), 0.4 * t_s, np.full_like(t_s, 0.05)], axis=1)
    p[t_s >= 10.0, 2] += step_m
    n = t_s.size
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return GroundTruth(np.round(t_s * S).astype(np.int64), p, q, v, np.zeros((n, 3)),
                       np.zeros((n, 3)))  # fmt: skip


def _deviation(step_m: float) -> np.ndarray:
    """Reference positions (N, 3) minus the velocity path tied at 2 s and 18 s."""
    gt = _reference(step_m)
    a_ns, b_ns = 2 * S, 18 * S
    m = (gt.t_ns >= a_ns) & (gt.t_ns <= b_ns)
    return gt.p_W_B[m] - _bench().velocity_path(gt, gt.t_ns[m], a_ns, b_ns)


def test_a_reference_whose_velocity_matches_its_positions_is_its_own_velocity_path() -> None:
    # Only the trapezoid rule's error over steps up to 0.25 s.
    assert np.abs(_deviation(0.0)).max() < 0.01


def test_a_height_step_without_vertical_velocity_shows_against_the_velocity_path() -> None:
    dev = _deviation(0.5)
    # Tied at both ends, the path climbs the 0.5 m evenly: half of it at the step.
    assert 0.2 < np.abs(dev[:, 2]).max() < 0.3
    assert np.abs(dev[:, :2]).max() < 0.01
