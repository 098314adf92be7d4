"""TUM trajectory I/O: exact round trip, real files, and bad input messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.trajectory import (
    ns_to_seconds_text,
    read_tum,
    seconds_text_to_ns,
    write_groundtruth_tum,
    write_tum,
)
from svains.errors import DatasetError

TRAJ = Path(__file__).resolve().parents[1].parent / "shared/data/trajectories"


def test_round_trip_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t = 1_403_715_273_262_142_976 + np.cumsum(rng.integers(1, 10**8, 50)).astype(np.int64)
    p = rng.normal(size=(50, 3)) * 10
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    write_tum(tmp_path / "a.tum", t, p, q, comment="test")
    t2, p2, q2 = read_tum(tmp_path / "a.tum")
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_array_equal(p2, p)
    np.testing.assert_array_equal(q2, q)
    first = (tmp_path / "a.tum").read_text().splitlines()[2].split()
    # TUM order is qx qy qz qw; seconds carry all nine ns digits.
    assert float(first[7]) == q[0, 0] and float(first[4]) == q[0, 1]
    assert first[0] == ns_to_seconds_text(int(t[0]))


def test_seconds_text_exact() -> None:
    assert ns_to_seconds_text(1403715273262142976) == "1403715273.262142976"
    assert seconds_text_to_ns("1403715273.262142976") == 1403715273262142976
    assert seconds_text_to_ns("1.5e-3") == 1_500_000
    assert ns_to_seconds_text(-5) == "-0.000000005"


@pytest.mark.realdata  # a trajectory of ../shared/data/trajectories
def test_read_real_euroc_tum() -> None:
    t, p, q = read_tum(TRAJ / "euroc_V1_02_medium_groundtruth.tum")
    assert t[0] == 1403715524907140000
    np.testing.assert_array_equal(p[0], [0.515356, 1.996773, 0.971104])
    np.testing.assert_array_equal(q[0], [0.161996, 0.789985, -0.205376, 0.554528])
    assert 1e9 / np.median(np.diff(t)) == pytest.approx(200.0, rel=1e-3)


def test_groundtruth_to_tum(tmp_path: Path, euroc_micro: Path) -> None:
    gt = load_dataset(euroc_micro).groundtruth
    write_groundtruth_tum(tmp_path / "gt.tum", gt)
    t, p, q = read_tum(tmp_path / "gt.tum")
    np.testing.assert_array_equal(t, gt.t_ns)
    np.testing.assert_array_equal(p, gt.p_W_B)
    np.testing.assert_array_equal(q, gt.q_W_B_wxyz)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("1.0 1 2 3 0 0 0 1\n2.0 1 2 3 0 0 1\n", r"x\.tum:2: malformed TUM row, expected 8"),
        ("1.0 1 2 3 0 0 0 1\n2.0 1 2 zz 0 0 0 1\n", r"x\.tum:2: malformed number"),
        ("# c\n1.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 0 1\n", r"x\.tum:3: duplicate timestamp"),
        ("2.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 0 1\n", r"x\.tum:2: non-increasing timestamp"),
        ("1.0 1 nan 3 0 0 0 1\n", r"x\.tum:1: NaN"),
        ("# only a comment\n", r"no poses in TUM file"),
        ("1317045935637923328 1 2 3 0 0 0 1\n",
         r"x\.tum:1: time 1317045935637923328 s is outside the int64 ns range: a TUM file's "
         r"stamps are seconds; these look like nanoseconds \(divide by 1e\+09\)$"),
        ("1317045935637923 1 2 3 0 0 0 1\n", r"these look like microseconds \(divide by 1e\+06\)$"),
        ("1317045935637 1 2 3 0 0 0 1\n", r"these look like milliseconds \(divide by 1e\+03\)$"),
    ],
)
def test_bad_tum(tmp_path: Path, body: str, match: str) -> None:
    (tmp_path / "x.tum").write_text(body)
    with pytest.raises(DatasetError, match=match):
        read_tum(tmp_path / "x.tum")


def test_missing_tum(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"missing file: .*nope\.tum"):
        read_tum(tmp_path / "nope.tum")
