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


def _no_temporary_folder(**kw: object) -> object:
    raise FileNotFoundError(2, "No usable temporary directory found")


@pytest.mark.parametrize(("make", "said"), [
    (lambda **kw: open("/dev/full", "w+b", buffering=0), "[Errno 28]"),  # noqa: SIM115
    (_no_temporary_folder, "No usable temporary directory found"),
])
def test_a_full_temporary_folder_keeps_the_tracks_in_memory_with_one_warning(
    make: object, said: str, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Two reviews' cases: with the temporary folder full, ENOSPC ended the run (a live
    Navigator too) with `[Errno 28] No space left on device` and no outputs; with none usable,
    the warning's own look-up of the folder raised again."""
    monkeypatch.setattr(track_log, "SPOOL_ROWS", 50)
    monkeypatch.setattr(track_log.tempfile, "TemporaryFile", make)
    want = _frames(60, seed=2)
    log = TrackLog()
    with caplog.at_level("WARNING", logger="svains.navigation.track_log"):
        for f in want:
            log.add(*f)
    assert caplog.text.count("could not be spilled to a temporary file") == 1
    assert said in caplog.text
    assert log._offsets == [] and len(log) == 60
    _same(list(log.frames), want)


class _Rectifier:
    """A stand-in holding remap tables as large as a real rectifier's."""

    def __init__(self) -> None:
        self.maps = np.zeros((4, 1000, 1000))

    def unrectify(self, uv: np.ndarray) -> np.ndarray:
        return uv + 2.0


def test_a_pickled_log_carries_its_raw_pixels_not_the_rectifier() -> None:
    """A review's case: the bound map dragged the rectifier's tables along, 20 MB per run."""
    want = _frames(8, seed=3)
    log = TrackLog()
    for f in want:
        log.add(*f)
    log.make_raw(_Rectifier().unrectify)
    data = pickle.dumps(log)
    assert len(data) < 100_000
    back = pickle.loads(data)
    assert back.raw and back._map is None and back._mem_rows == sum(f[1].size for f in want)
    _same(list(back.frames), want, shift=2.0)
