"""KITTI-style drift figures of report.json against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from svains.evaluation.accuracy import drift_report, segment_drift_pct
from svains.evaluation.compare import comparison_markdown
from svains.geometry.rotation import so3_exp


def _straight(n: int = 151) -> tuple[np.ndarray, np.ndarray]:
    """Positions along x every 1 m (n,) with identity attitudes."""
    p = np.zeros((n, 3))
    p[:, 0] = np.arange(n, dtype=float)
    return p, np.tile(np.eye(3), (n, 1, 1))


def test_scale_error_gives_its_percentage() -> None:
    p, R = _straight()
    p_est = p * 1.01  # 1 % too long: 0.5 m over every 50 m segment, 1.5 m at the end
    out = drift_report(p_est, R, p, R)
    assert out["path_length_m"] == pytest.approx(150.0)
    assert out["final_error_m"] == pytest.approx(1.5)
    assert out["final_error_pct"] == pytest.approx(1.0)
    assert out["drift_50m_pct"] == pytest.approx(1.0)
    assert out["drift_100m_pct"] == pytest.approx(1.0)


def test_heading_error_of_the_estimate_bends_every_segment() -> None:
    # Positions turned by θ about z, attitudes exact: each 50 m segment (in the start's body
    # frame) is off by 50 * 2 sin(θ/2) m.
    p, R = _straight()
    theta = 0.02
    p_est = p @ so3_exp(np.array([0.0, 0.0, theta])).T
    assert segment_drift_pct(p_est, R, p, R, 50.0) == pytest.approx(200.0 * np.sin(theta / 2))


def test_drift_ignores_a_rigid_transform_and_short_paths_give_none() -> None:
    p, R = _straight()
    rng = np.random.default_rng(0)
    p_est = p * 1.02 + rng.normal(scale=0.01, size=p.shape)
    ref = segment_drift_pct(p_est, R, p, R, 50.0)
    G = so3_exp(np.array([0.1, -0.2, 0.7]))
    moved = segment_drift_pct(p_est @ G.T + [5.0, -3.0, 1.0], G @ R, p, R, 50.0)
    assert moved == pytest.approx(ref, rel=1e-12)
    assert ref == pytest.approx(2.0, abs=0.1)
    assert segment_drift_pct(p[:40], R[:40], p[:40], R[:40], 50.0) is None
    assert drift_report(p[:40], R[:40], p[:40], R[:40])["drift_100m_pct"] is None


def test_compare_table_shows_the_drift_columns() -> None:
    md = comparison_markdown({"3d": {"drift_50m_pct": 0.5, "drift_100m_pct": 0.75}}, "t")
    assert "drift 50 m [%]" in md and "| 0.50 | 0.75 |" in md
