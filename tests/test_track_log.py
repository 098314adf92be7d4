"""The run's track log (``navigation.track_log``): spilled to a temporary file past
``SPOOL_ROWS`` rows, read back whole and in order, raw pixels mapped as read, picklable."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from svains.navigation import track_log
from svains.navigation.track_log import TrackLog


def _frames(n: int, seed: int = 0) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        m = int(rng.integers(0, 30))  # empty frames too
        out.append((10**18 + k * 50_000_000, rng.integers(0, 10**12, m),
                    rng.normal(size=(m, 2)) * 300, rng.random(m) > 0.3))  # fmt: skip
    return out


def _same(got: list, want: list, shift: float = 0.0) -> None:
    assert len(got) == len(want)
    for (t, ids, uv, inl), (t0, ids0, uv0, inl0) in zip(got, want, strict=True):
        assert t == t0 and ids.dtype == np.int64 and np.array_equal(ids, ids0)
        assert uv.dtype == np.float32
        np.testing.assert_allclose(uv, uv0 + shift, rtol=0, atol=1e-4)
        assert np.array_equal(inl, inl0)


def test_a_long_log_spills_and_reads_back_whole_in_order(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 30-minute `3d` run kept 188 MB of tracks in memory (a user's probe)."""
    monkeypatch.setattr(track_log, "SPOOL_ROWS", 50)
    want = _frames(60)
    log = TrackLog()
    for k, f in enumerate(want):
        log.add(*f)
        if k == 29:
            _same(list(log.frames), want[:30])  # read in the middle, then added to
    assert len(log) == 60 and len(log._offsets) >= 10 and log._mem_rows < 50
    _same(list(log.frames), want)
    _same(list(log.frames), want)  # read twice
    back = pickle.loads(pickle.dumps(log))  # a temporary file does not travel; its frames do
    assert back._spool is None and len(back) == 60
    _same(list(back.frames), want)


def test_raw_pixels_are_mapped_as_read_and_only_once() -> None:
    want = _frames(8, seed=1)
    log = TrackLog()
    for f in want:
        log.add(*f)
    log.make_raw(lambda uv: uv + 2.0)
    log.make_raw(lambda uv: uv + 100.0)  # raw already: not mapped twice
    assert log.raw
    _same(list(log.frames), want, shift=2.0)
