"""The tc/3d frame test (issue 26: accepting a frame when a tenth of its features pass, instead
of half, survived the suite).

One exact stereo frame pair (``test_vision_updater``'s), some features moved 40 px along their
row: every moved feature fails its own gate. A frame whose passing features are fewer than
``frame_min_inlier_fraction`` of its valid ones is refused and counted, and the state is left
as it was; with more passing features the frame is fused through them.
"""

from __future__ import annotations

import numpy as np
import pytest

from _nav_feed import updater_for
from _vision_truth import two_frames
from svains.models.state import V
from svains.navigation.options import VisionOptions
from test_vision_updater import DT_S, RIG, _ctx, _dataset, _ukf


@pytest.mark.parametrize("method", ["3d", "tc"])
@pytest.mark.parametrize(("corrupt", "fused"), [(25, True), (35, False)])
def test_frame_is_refused_below_its_inlier_fraction(method: str, corrupt: int,
                                                    fused: bool) -> None:  # fmt: skip
    tf = two_frames(RIG, DT_S, np.array([0.1, -0.2, 0.3]), np.zeros(3), n_features=60)
    opts = VisionOptions(rotation="linear")
    assert opts.frame_min_inlier_fraction == 0.5  # 30 of the 60 features must pass
    upd = updater_for(method, _dataset(tf, corrupt=corrupt, seed=1), opts)
    ukf = _ukf(tf.x_k, np.array([0.05, -0.05, 0.02]))
    x_before = ukf.x.copy()
    stats = upd.update(_ctx(ukf))
    s = upd.summary()
    assert stats is not None and stats.accepted is fused
    assert s["features_gated"] == corrupt, s
    if fused:
        assert s["frames_fused"] == 1 and s["features_fused"] == 60 - corrupt, s
        assert np.linalg.norm(ukf.x[V] - tf.x_k[V]) < 0.04  # prior error 0.073 m/s
    else:
        assert s["frames_rejected"] == 1 and s["frames_gated"] == 1 and s["frames_fused"] == 0
        np.testing.assert_array_equal(ukf.x, x_before)
