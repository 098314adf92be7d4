"""Re-acquisition by descriptors across gaps: windows from a prior, whole-image matching, and
KITTI raw at ~1 Hz and with random gaps up to 3 s (subsets of the shared set, nothing copied)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from svains.datasets import load_dataset, stereo_pairs
from svains.datasets.types import Dataset
from svains.frontend import pipeline
from svains.frontend.egomotion import RansacOptions, estimate_egomotion
from svains.frontend.options import FrontendOptions
from svains.frontend.pipeline import StereoFrontend
from svains.frontend.reacquire import (
    ReacquireOptions,
    match_global,
    match_in_windows,
    predict_pixels,
)
from svains.frontend.run import groundtruth_camera_poses, run_frontend
from svains.frontend.types import Egomotion
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp, so3_log
from test_frontend_pipeline import RIG as PLANE_RIG
from test_frontend_pipeline import _pair, _texture

RIG = RectifiedStereo(500.0, 320.0, 240.0, 0.5, np.eye(3), np.zeros(3), 640, 480)


def test_predicted_pixel_spread_matches_sampled_motions() -> None:
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-4, 4, 5), rng.uniform(-2, 2, 5), rng.uniform(6, 30, 5)])
    R = so3_exp(np.array([0.01, -0.05, 0.002]))
    t = np.array([0.1, 0.0, -1.5])
    cov = np.diag([1e-4, 4e-4, 1e-4, 0.01, 0.004, 0.04])
    opts = ReacquireOptions(pixel_std=0.0, disparity_std=0.0)
    uv, S, ok = predict_pixels(RIG, p, Egomotion(R, t, cov), opts)
    assert ok.all()
    np.testing.assert_allclose(uv, RIG.project(p @ R.T + t), atol=1e-9)
    d = rng.multivariate_normal(np.zeros(6), cov, 20000)
    samples = np.stack([RIG.project(p @ (R @ so3_exp(di[:3])).T + t + di[3:]) for di in d])
    emp = np.einsum("sni,snj->nij", samples - uv, samples - uv) / len(d)
    # Linearised vs sampled: within 10 % of the spread on each entry's two axes.
    scale = np.sqrt(np.einsum("nii->ni", emp)[:, :, None] * np.einsum("nii->ni", emp)[:, None])
    assert np.all(np.abs(S - emp) <= 0.1 * scale + 0.5)


def test_window_match_ignores_better_descriptors_outside() -> None:
    rng = np.random.default_rng(1)
    desc_ref = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    near = desc_ref.copy()
    near[0, :3] ^= 0xFF  # 24 bits off, inside the window
    uv_cur = np.array([[105.0, 100.0], [300.0, 300.0]])
    desc_cur = np.vstack([near, desc_ref])  # the exact copy lies far outside the window
    cov = np.eye(2)[None] * 16.0
    i_r, i_c = match_in_windows(np.array([[100.0, 100.0]]), cov, desc_ref, uv_cur, desc_cur,
                                ReacquireOptions())  # fmt: skip
    assert i_r.tolist() == [0] and i_c.tolist() == [0]
    # Whole image: the exact copy wins; an ambiguous pair (two equal candidates) is dropped.
    i_r, i_c = match_global(np.vstack([desc_ref, near]), desc_cur, ReacquireOptions())
    assert sorted(zip(i_r.tolist(), i_c.tolist(), strict=True)) == [(0, 1), (1, 0)]
    i_r, _ = match_global(desc_ref, np.vstack([desc_ref, desc_ref]), ReacquireOptions())
    assert i_r.size == 0


@pytest.fixture(scope="module")
def kitti(kitti_raw: Path) -> tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]:
    ds = load_dataset(kitti_raw)
    t, il, ir = stereo_pairs(ds)
    return ds, t, il, ir


def test_one_second_gap_needs_descriptors(kitti: tuple) -> None:  # type: ignore[type-arg]
    """Pairs 5 and 10 (1.0 s, 6.8 m apart, in the first turn): KLT alone finds no consensus,
    descriptors do (243 inliers measured)."""
    ds, t, il, ir = kitti
    sel = np.array([5, 10])
    got = {}
    for on in (False, True):
        opts = FrontendOptions(reacquire=ReacquireOptions(enabled=on))
        run = run_frontend(ds, (t[sel], il[sel], ir[sel]), opts)
        got[on] = run.records[1]
    assert got[False].egomotion is None and got[False].stats.status == "no_consensus"
    rec = got[True]
    assert rec.egomotion is not None and rec.stats.inliers >= 100
    assert rec.translation_error_m < 0.04 * rec.gt_translation_m
    assert rec.rotation_error_deg < 0.4


@pytest.mark.slow
def test_every_fifth_frame_yields_motion(kitti: tuple) -> None:  # type: ignore[type-arg]
    """~1 Hz (every 5th pair, 5-8 m steps), no prior: whole-image matching."""
    ds, t, il, ir = kitti
    sel = np.arange(0, t.size, 5)
    run = run_frontend(ds, (t[sel], il[sel], ir[sel]))
    recs = run.records[1:]
    assert [r.stats.status for r in recs] == ["ok"] * len(recs)
    rel = [r.translation_error_m / r.gt_translation_m for r in recs]
    assert np.median(rel) < 0.04
    assert np.median([r.rotation_error_deg for r in recs]) < 0.2


def _random_gaps(t: np.ndarray, seed: int, max_gap_s: float = 3.0) -> np.ndarray:
    """Indices kept after dropping each pair with probability 0.6 and one run of pairs
    spanning a gap just under ``max_gap_s``; no gap exceeds it."""
    rng = np.random.default_rng(seed)
    keep = np.flatnonzero(rng.random(t.size) > 0.6)
    a = int(rng.integers(5, t.size // 2))
    b = int(np.searchsorted(t, t[a] + max_gap_s * 1e9, side="right") - 1)
    keep = np.union1d(keep[(keep <= a) | (keep >= b)], [0, a, b, t.size - 1])
    while (gaps := np.diff(t[keep]) * 1e-9).max() > max_gap_s:
        j = int(np.argmax(gaps))
        keep = np.union1d(keep, [(keep[j] + keep[j + 1]) // 2])
    return keep


@pytest.mark.slow
def test_random_gaps_with_prior_yield_motion(kitti: tuple) -> None:  # type: ignore[type-arg]
    """First half of the drive, random drops with gaps up to 3 s, and a motion prior (the
    reference motion, perturbed within its covariance, as the IMU would give): windowed
    matching; every frame gets a motion and it agrees with the reference."""
    ds, t, il, ir = kitti
    sel = _random_gaps(t[:90], seed=4)
    assert 2.5 < np.diff(t[sel]).max() * 1e-9 <= 3.0
    fe = StereoFrontend.from_calibration(ds.cam0, ds.cam1)
    T = groundtruth_camera_poses(ds.groundtruth, t[sel], fe.rig.R_B_C, fe.rig.p_B_C)
    rng = np.random.default_rng(5)
    errors = []
    for k, i in enumerate(sel):
        prior = None
        if k > 0:
            T_rel = np.linalg.inv(T[k]) @ T[k - 1]
            dt_s = (t[i] - t[sel[k - 1]]) * 1e-9
            std = np.array([3e-3 * dt_s] * 3 + [0.1 * dt_s] * 3)
            d = rng.normal(0.0, std)
            prior = Egomotion(T_rel[:3, :3] @ so3_exp(d[:3]), T_rel[:3, 3] + d[3:],
                              np.diag((2.0 * std) ** 2))  # fmt: skip
        tracks = fe.process(int(t[i]), ds.left.load(int(il[i])), ds.right.load(int(ir[i])),
                            motion_prior=prior)  # fmt: skip
        if k == 0:
            continue
        assert tracks is not None and tracks.egomotion is not None, (k, fe.stats.status)
        ego = tracks.egomotion
        errors.append((np.linalg.norm(ego.p_Ck_Ckm1 - T_rel[:3, 3]) / np.linalg.norm(T_rel[:3, 3]),
                       np.degrees(np.linalg.norm(so3_log(T_rel[:3, :3].T @ ego.R_Ck_Ckm1)))))
    e = np.array(errors)
    assert np.median(e[:, 0]) < 0.04 and np.median(e[:, 1]) < 0.2
    assert e[:, 1].max() < 1.0


def test_reacquire_options_reach_ransac(monkeypatch: pytest.MonkeyPatch) -> None:
    """The long-gap RANSAC settings reach the RANSAC call of the re-acquired matches (and the
    tracking ones the KLT calls): the synthetic plane's sudden reversal of
    ``test_frontend_pipeline`` with the KLT retry off, so only descriptors find the motion."""
    o = FrontendOptions()
    assert o.reacquire.ransac_inlier_px > o.ransac.inlier_px  # else the setting is moot
    seen: list[RansacOptions] = []

    def recording(*args: Any, **kwargs: Any) -> Any:
        seen.append(args[4])  # estimate_egomotion(p_prev, uv_left, uv_right, rig, opts, ...)
        return estimate_egomotion(*args, **kwargs)

    monkeypatch.setattr(pipeline, "estimate_egomotion", recording)
    # Values of their own (not the defaults) so a call with the wrong options cannot match.
    opts = FrontendOptions(retry_levels=0, ransac=RansacOptions(iterations=47),
                           reacquire=ReacquireOptions(ransac_inlier_px=3.25, min_inliers=11,
                                                      ransac_iterations=93))
    fe = StereoFrontend.from_rig(PLANE_RIG, opts)
    tex = _texture(3, (240, 700))
    tracks = [fe.process(k, *_pair(tex, s)) for k, s in enumerate([100, 140, 180, 140])]
    assert fe.stats.status == "ok" and "reacquire" in fe.stats.timings_ms
    assert tracks[3] is not None and tracks[3].egomotion is not None
    assert tracks[3].egomotion.p_Ck_Ckm1 == pytest.approx([0.4, 0.0, 0.0], abs=0.01)
    long_gap = [r for r in seen if r.inlier_px == 3.25]
    assert long_gap, [(r.inlier_px, r.min_inliers) for r in seen]
    assert all(r.min_inliers == 11 and r.iterations == 93 for r in long_gap)
    tracking = [r for r in seen if r.inlier_px == o.ransac.inlier_px]
    assert len(tracking) >= 3 and all(r.min_inliers == o.ransac.min_inliers for r in tracking)
    assert all(r.iterations == 47 for r in tracking)
    assert len(tracking) + len(long_gap) == len(seen)


@pytest.mark.parametrize("with_prior", [True, False])
def test_windowed_matches_take_their_own_inlier_fraction(
    monkeypatch: pytest.MonkeyPatch, with_prior: bool
) -> None:
    """Matches made inside a motion prior's windows are held to
    ``min_inlier_fraction_with_prior`` (repeated textures fill the windows with wrong
    candidates, and the motion is checked against the prior); whole-image matches and KLT
    tracks keep the front end's ``min_inlier_fraction``. The plane's reversal as above; every
    KLT motion is checked against re-acquisition (``klt_min_inliers``)."""
    seen: list[float | None] = []
    original = StereoFrontend._egomotion

    def recording(self: StereoFrontend, *args: Any, **kwargs: Any) -> Any:
        seen.append(args[8] if len(args) > 8 else kwargs.get("min_fraction"))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(StereoFrontend, "_egomotion", recording)
    opts = FrontendOptions(retry_levels=0, min_inlier_fraction=0.31, reacquire=ReacquireOptions(
        min_inlier_fraction_with_prior=0.123, klt_min_inliers=100_000))
    fe = StereoFrontend.from_rig(PLANE_RIG, opts)
    tex = _texture(3, (240, 700))
    for k, s in enumerate([100, 140, 180]):
        fe.process(k, *_pair(tex, s))
    prior = Egomotion(np.eye(3), np.array([0.4, 0.0, 0.0]),
                      np.diag([1e-4] * 3 + [1e-2] * 3)) if with_prior else None  # fmt: skip
    seen.clear()
    tracks = fe.process(3, *_pair(tex, 140), motion_prior=prior)
    assert "reacquire" in fe.stats.timings_ms
    assert tracks is not None and tracks.egomotion is not None
    assert tracks.egomotion.p_Ck_Ckm1 == pytest.approx([0.4, 0.0, 0.0], abs=0.01)
    assert seen[0] is None  # the KLT tracks: the front end's own fraction
    reacquired = seen[1:]
    assert reacquired and all(f == (0.123 if with_prior else None) for f in reacquired), seen


def test_refused_klt_motion_is_reacquired(monkeypatch: pytest.MonkeyPatch) -> None:
    """A KLT motion the front end refuses (here made to contradict the prior) leaves the frame
    as unlinked as no consensus does: descriptors are tried and give the motion (rendered
    keyframes, V1_02 seed 2: 30 KLT tracks across 1.9 s agreed on a motion the prior refused,
    and the frame fused nothing)."""
    checks: list[bool] = []

    def first_refused(ego: Egomotion, prior: Egomotion, gate_chi2: float) -> bool:
        checks.append(bool(checks))  # the first check (the KLT motion) fails, later ones pass
        return checks[-1]

    monkeypatch.setattr(pipeline, "agrees_with_prior", first_refused)
    fe = StereoFrontend.from_rig(PLANE_RIG, FrontendOptions(retry_levels=0))
    tex = _texture(3, (240, 700))
    for k, s in enumerate([100, 140, 180]):
        fe.process(k, *_pair(tex, s))
    prior = Egomotion(np.eye(3), np.array([0.4, 0.0, 0.0]), np.diag([1e-4] * 3 + [1e-2] * 3))
    tracks = fe.process(3, *_pair(tex, 140), motion_prior=prior)
    assert checks[0] is False and len(checks) > 1, checks
    assert "reacquire" in fe.stats.timings_ms and fe.stats.status == "ok"
    assert tracks is not None and tracks.egomotion is not None
    assert tracks.egomotion.p_Ck_Ckm1 == pytest.approx([0.4, 0.0, 0.0], abs=0.01)
