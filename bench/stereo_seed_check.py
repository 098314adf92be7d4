"""How good are the left-right seeds, and what does a pyramid level change? (one data set)

Runs the stereo front end once over a data set's stereo pairs (no motion prior: it predicts from
its last motion, as in a ``3d`` run with the default ``VisionOptions``) and, at every left-right
match, matches the same features again three ways without changing the run:

- **tracked** features (seeded with the disparity predicted from their 3-D point and the motion):
  the reference is a row search + base-level KLT (the start new corners get); reported are the
  seed error ``|d_pred - d_ref|`` (features whose reference is valid), the failures and the
  matches more than 1 px from the reference, with the run's levels and with one level more
  from the same seed, and whether the seed change ``|d_pred - d_prev|`` flags the bad seeds;
- **new** corners (row-search seed): how many pass with the run's levels and with one more.

    python bench/stereo_seed_check.py DATASET

Evidence for ``StereoMatchOptions.klt_levels`` = 0 (2026-12, this script, no level above the
base in the run): the tracked seeds are good, p99 error 2.9 px on the 2 Hz demo flight
(``svains demo``, 43 k seeds, 604 off by > 2 px, median 35 px off for the wrong ones: a wrong
earlier disparity or an ambiguous row search, not a motion too large for the prediction; the seed
change flags 19 of them), 0.42 px on the 20 Hz flight and 0.34 px on EuRoC V1_01 micro. One
level more from the same seeds fails 50 (demo) against 36, 255 (20 Hz) against 0 and 1670
(EuRoC, 8.6 %) against 0, and leaves 43 against 57 (demo) more than 1 px from the reference. New
corners: the base level alone keeps 66 of 17.9 k more on the demo, 75 of 1.7 k on EuRoC.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

import svains.frontend.pipeline as pipeline
from svains.datasets import load_dataset, stereo_pairs
from svains.threads import limit_threads

match_sparse = pipeline.match_sparse


def collect(data: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Per-feature arrays of every tracked (seeded) and new-corner left-right match of a run."""
    keys = ("seed", "prev", "ref", "ok_ref", "d0", "ok0", "d1", "ok1")
    tracked: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    new: dict[str, list[np.ndarray]] = {"ok0": [], "ok1": []}
    d_prev: list[np.ndarray] = []
    track_temporal = pipeline.StereoFrontend._track_temporal

    def _track(self, ref, *a, **k):  # type: ignore[no-untyped-def]
        got = track_temporal(self, ref, *a, **k)
        d_prev.append((ref.uv_left[:, 0] - ref.uv_right[:, 0])[got[1]])
        return got

    def _match(left, right, uv, opts, klt, guess=None, rectifier=None):  # type: ignore[no-untyped-def]
        uv_r, ok = match_sparse(left, right, uv, opts, klt, guess, rectifier)
        g = np.full(uv.shape[0], np.nan) if guess is None else np.asarray(guess, float)
        up = replace(opts, klt_levels=opts.klt_levels + 1)
        s = np.isfinite(g)
        if s.any():
            r_ref, ok_ref = match_sparse(left, right, uv[s], opts, klt, None, rectifier)
            r1, ok1 = match_sparse(left, right, uv[s], up, klt, g[s], rectifier)
            prev = d_prev[-1] if d_prev and d_prev[-1].size == s.sum() else np.full(s.sum(), np.nan)
            for k, v in (("seed", g[s]), ("prev", prev), ("ref", uv[s, 0] - r_ref[:, 0]),
                         ("ok_ref", ok_ref), ("d0", uv[s, 0] - uv_r[s, 0]), ("ok0", ok[s]),
                         ("d1", uv[s, 0] - r1[:, 0]), ("ok1", ok1)):  # fmt: skip
                tracked[k].append(v)
        if (~s).any():
            _, ok1 = match_sparse(left, right, uv[~s], up, klt, None, rectifier)
            new["ok0"].append(ok[~s])
            new["ok1"].append(ok1)
        return uv_r, ok

    pipeline.match_sparse = _match
    pipeline.StereoFrontend._track_temporal = _track  # type: ignore[method-assign]
    try:
        ds = load_dataset(data)
        t_ns, il, ir = stereo_pairs(ds)
        fe = pipeline.StereoFrontend.from_calibration(ds.cam0, ds.cam1)  # type: ignore[arg-type]
        for t, a, b in zip(t_ns, il, ir, strict=True):
            fe.process(int(t), ds.left.load(int(a)), ds.right.load(int(b)))  # type: ignore[union-attr]
    finally:
        pipeline.match_sparse = match_sparse
        pipeline.StereoFrontend._track_temporal = track_temporal  # type: ignore[method-assign]
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in tracked.items()}
    return cat, {k: np.concatenate(v) if v else np.zeros(0) for k, v in new.items()}


def report(tr: dict[str, np.ndarray], new: dict[str, np.ndarray]) -> None:
    ok_ref = tr["ok_ref"].astype(bool)
    err = np.abs(tr["seed"] - tr["ref"])
    print(f"tracked {err.size}: reference valid {ok_ref.sum()}")
    e = err[ok_ref]
    p50, p90, p99 = np.percentile(e, [50, 90, 99])
    print(f"  seed error px p50 {p50:.2f} p90 {p90:.2f} p99 {p99:.2f}; "
          f"> 2 px {(e > 2).sum()}, > 4 px {(e > 4).sum()}")
    for name, m in (("all", ok_ref), ("seed error > 2 px", ok_ref & (err > 2))):
        line = f"  {name} ({m.sum()}):"
        for lv in ("0", "1"):
            ok = tr["ok" + lv].astype(bool)
            wrong = m & ok & (np.abs(tr["d" + lv] - tr["ref"]) > 1.0)
            line += f" +{lv} level: fail {(m & ~ok).sum()} wrong {wrong.sum()};"
        print(line)
    change = np.abs(tr["seed"] - tr["prev"])
    bad = ok_ref & (err > 2)
    for th in (1.0, 2.0):
        flag = change > th
        print(f"  seed change > {th:g} px flags {flag.mean() * 100:.1f} % of seeds and "
              f"{(flag & bad).sum()} of the {bad.sum()} seeds off by > 2 px")
    n0, n1 = new["ok0"].astype(bool), new["ok1"].astype(bool)
    print(f"new corners {n0.size}: matched {n0.sum()} (+1 level: {n1.sum()}); "
          f"only without the level {(n0 & ~n1).sum()}, only with it {(n1 & ~n0).sum()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", type=Path)
    args = ap.parse_args()
    with limit_threads(None):
        report(*collect(args.data))


if __name__ == "__main__":
    main()
