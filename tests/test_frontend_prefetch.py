"""The image track source decodes the next stereo pair in a background thread: same tracks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svains.datasets import load_dataset
from svains.errors import DatasetError
from svains.navigation.vision_sources import ImageTrackSource


def _same(a: object, b: object) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return all(
        np.array_equal(getattr(a, k), getattr(b, k))
        for k in ("track_id", "uv_left", "uv_right", "uv_left_prev", "inlier")
    )


def test_prefetch_gives_the_same_tracks_in_order_and_out_of_order(euroc_micro: Path) -> None:
    ds = load_dataset(euroc_micro)
    fast = ImageTrackSource(ds, frame_stride=3, prefetch=True)
    slow = ImageTrackSource(ds, frame_stride=3, prefetch=False)
    times = fast.frame_times()
    # In order, then a jump back and forward (stale prefetches must not be served).
    order = [*times[:6], times[2], times[8], times[9]]
    for t in order:
        tr_fast, tr_slow = fast.tracks_at(int(t)), slow.tracks_at(int(t))
        assert _same(tr_fast, tr_slow), f"frame {t}"
    assert fast.tracks_at(int(times[5]) + 1) is None  # not a frame time
    assert len(fast.load_ms) == len(fast.frontend_ms) == len(fast.stage_ms) == len(order)
    assert all("track" in d for d in fast.stage_ms[1:6])
    fast.close()
    assert fast._pool is None


def test_prefetch_reports_an_unreadable_image(euroc_micro: Path, tmp_path: Path) -> None:
    ds = load_dataset(euroc_micro)
    assert ds.left is not None
    src = ImageTrackSource(ds, prefetch=True)
    t = src.frame_times()
    # Break the second left image: the prefetch of frame 1 fails, the error surfaces at frame 1.
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png")
    paths = list(ds.left.paths)
    k = int(np.searchsorted(ds.left.t_ns, t[1]))
    paths[k] = bad
    object.__setattr__(ds.left, "paths", tuple(paths))
    src.tracks_at(int(t[0]))
    with pytest.raises(DatasetError, match="unreadable image"):
        src.tracks_at(int(t[1]))
    src.close()


def test_motion_prior_reaches_the_front_end(euroc_micro: Path) -> None:
    from svains.frontend.types import Egomotion

    ds = load_dataset(euroc_micro)
    src = ImageTrackSource(ds, frame_stride=2)
    t = src.frame_times()
    src.tracks_at(int(t[0]))
    # The MAV is static: a confident prior of a 1 m step contradicts the measured motion.
    wrong = Egomotion(R_Ck_Ckm1=np.eye(3), p_Ck_Ckm1=np.array([1.0, 0.0, 0.0]),
                      cov=np.eye(6) * 1e-6)
    tr = src.tracks_at(int(t[1]), motion_prior=wrong)
    assert tr is not None and tr.egomotion is None
    assert src.frontend.stats.status == "contradicts_prior"
    right = Egomotion(R_Ck_Ckm1=np.eye(3), p_Ck_Ckm1=np.zeros(3), cov=np.eye(6) * 1e-4)
    tr = src.tracks_at(int(t[2]), motion_prior=right)
    assert tr is not None and tr.egomotion is not None
    assert np.linalg.norm(tr.egomotion.p_Ck_Ckm1) < 0.005
    src.close()


def test_reference_time_and_status_counts_follow_the_front_end(euroc_micro: Path) -> None:
    """A prior must span [reference, t_k]: a frame rejected against its prior is held, so the
    reference stays at the last good frame (the updater then builds the next prior from it)."""
    from svains.frontend.types import Egomotion

    ds = load_dataset(euroc_micro)
    src = ImageTrackSource(ds, frame_stride=2)
    t = [int(v) for v in src.frame_times()[:3]]
    assert src.reference_time_ns() is None
    src.tracks_at(t[0])
    assert src.reference_time_ns() == t[0]
    wrong = Egomotion(R_Ck_Ckm1=np.eye(3), p_Ck_Ckm1=np.array([1.0, 0.0, 0.0]),
                      cov=np.eye(6) * 1e-6)
    src.tracks_at(t[1], motion_prior=wrong)
    assert src.reference_time_ns() == t[0]  # held: still the last good frame
    tr = src.tracks_at(t[2])
    assert tr is not None and tr.t_prev_ns == t[0]
    assert src.reference_time_ns() == t[2]
    assert src.status_counts == {"first": 1, "contradicts_prior": 1, "ok": 1}
    src.close()
