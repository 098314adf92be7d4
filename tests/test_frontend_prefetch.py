"""The replay decodes the next stereo pair in a background thread: same pairs, in order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.datasets.loader import stereo_pairs
from svains.replay.replay import _image_pairs


def test_prefetch_gives_the_pairs_in_order(euroc_micro: Path) -> None:
    ds = load_dataset(euroc_micro)
    assert ds.left is not None and ds.right is not None
    t, il, ir = stereo_pairs(ds)
    got = list(_image_pairs(ds, int(t[80])))
    assert [g[0] for g in got] == t[80:].tolist()
    for (_, _, (_, left, right)), a, b in zip(got, il[80:], ir[80:], strict=True):
        assert np.array_equal(left, ds.left.load(int(a)))
        assert np.array_equal(right, ds.right.load(int(b)))


def test_an_unreadable_image_drops_its_pair_with_a_warning(
    euroc_micro: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # One corrupt file is a dropped frame (as a driver's lost frame), not the end of the run.
    from dataclasses import replace

    ds = load_dataset(euroc_micro)
    assert ds.left is not None
    t, il, _ = stereo_pairs(ds)
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png")
    paths = list(ds.left.paths)
    paths[int(il[1])] = bad
    ds = replace(ds, left=replace(ds.left, paths=tuple(paths)))
    with caplog.at_level("WARNING", logger="svains.datasets.loader"):
        got = [g[0] for g in _image_pairs(ds, int(t[0]))]
    assert got == [int(t[0]), *t[2:].tolist()]  # every pair but the unreadable one
    assert f"stereo pair dropped (1 so far): unreadable image: {bad}" in caplog.text
