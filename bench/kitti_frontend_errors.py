"""Where does the front end's per-step egomotion error on a real data set come from?

Runs the stereo front end once and splits each frame's translation error against the reference
(``svains frontend``'s ``egomotion_translation_error_median_rel_step``) into scale
(``|t_est| / |t_ref|``) and direction (vertical/horizontal angle, left-camera axes), then asks
which part the reference itself explains:

- **time offset:** the reference is read at image stamps shifted by ``tau``; the ``tau`` that
  minimises the median step error is the camera-reference offset the data leave;
- **stamp jitter:** a late stamp at frame k lengthens step k-1 -> k and shortens k -> k+1, so
  the scale error of consecutive steps is anti-correlated (lag-1 correlation near -0.5 for
  white stamp noise); the speed times the frame-interval spread bounds its size;
- **range:** scale error by the median inlier disparity (a disparity bias shows as a scale
  error growing with range);
- **direction:** the median tilt (a camera-IMU rotation or rectification error) and its spread.

    python bench/kitti_frontend_errors.py [DATASET] [--shift-ms A:B:STEP] [--calib CAMCHAIN]

``--calib`` replaces the cameras' calibration (e.g. a run's ``camchain_estimated.yaml``).
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from svains.datasets.loader import load_dataset, stereo_pairs
from svains.frontend.run import groundtruth_camera_poses, run_frontend


def step_errors(ds, t_ns, rig, ego, prev_idx, tau_ns: int = 0):  # type: ignore[no-untyped-def]
    """Per-frame (scale, vertical deg, horizontal deg, relative step error, |t_ref|) against
    the reference read at ``t_ns + tau_ns``."""
    T = groundtruth_camera_poses(ds.groundtruth, t_ns + tau_ns, rig.R_B_C, rig.p_B_C)
    out = []
    for i, (e, j) in enumerate(zip(ego, prev_idx, strict=True)):
        if e is None or j < 0:
            out.append([np.nan] * 5)
            continue
        T_rel = np.linalg.inv(T[i]) @ T[j]
        t_ref, t_est = T_rel[:3, 3], np.asarray(e.p_Ck_Ckm1)
        # Direction of travel (camera at k-1 in the frame at k, negated: forward is +z).
        d_ref, d_est = -t_ref, -t_est
        out.append([
            np.linalg.norm(t_est) / np.linalg.norm(t_ref),
            np.degrees(np.arctan2(d_est[1], d_est[2]) - np.arctan2(d_ref[1], d_ref[2])),
            np.degrees(np.arctan2(d_est[0], d_est[2]) - np.arctan2(d_ref[0], d_ref[2])),
            np.linalg.norm(t_est - t_ref) / np.linalg.norm(t_ref),
            np.linalg.norm(t_ref),
        ])
    return np.array(out)


def robust_std(x):  # type: ignore[no-untyped-def]
    """1.4826 x the median absolute deviation."""
    x = np.asarray(x, float)
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def predicted_direction_std(e):  # type: ignore[no-untyped-def]
    """Front end's own standard deviation (rad) of its translation direction, per axis."""
    if e is None:
        return np.nan
    t = np.asarray(e.p_Ck_Ckm1)
    Ct = np.asarray(e.cov)[3:, 3:]
    u = t / np.linalg.norm(t)
    perp = np.eye(3) - np.outer(u, u)
    return float(np.sqrt(np.trace(perp @ Ct @ perp) / 2) / np.linalg.norm(t))


def reference_consistency(  # type: ignore[no-untyped-def]
    ds, t_ns, prev_idx, rig, v_late_ns: int = 30_000_000
):
    """Per step (vertical deg, horizontal deg, length ratio - 1, relative difference) of the
    reference's position increment against its velocity integrated over the same step (the
    README's 30 ms velocity latency removed), in left-camera axes at k-1: a floor on the
    reference's own step noise."""
    gt = ds.groundtruth
    tg = np.asarray(gt.t_ns, np.int64)
    out = np.full((len(t_ns), 4), np.nan)
    T = groundtruth_camera_poses(gt, t_ns, rig.R_B_C, rig.p_B_C)
    for i, j in enumerate(prev_idx):
        if j < 0:
            continue
        grid = np.linspace(t_ns[j], t_ns[i], 41).astype(np.int64)
        v = np.stack([np.interp(grid + v_late_ns, tg, gt.v_W_B[:, a]) for a in range(3)], 1)
        d_vel = np.trapezoid(v, grid * 1e-9, axis=0)
        p = np.stack([np.interp(t_ns[[j, i]], tg, gt.p_W_B[:, a]) for a in range(3)], 1)
        d_pos = p[1] - p[0]
        R_W_C = T[j][:3, :3]
        a_, b_ = R_W_C.T @ d_pos, R_W_C.T @ d_vel
        out[i] = [np.degrees(np.arctan2(a_[1], a_[2]) - np.arctan2(b_[1], b_[2])),
                  np.degrees(np.arctan2(a_[0], a_[2]) - np.arctan2(b_[0], b_[2])),
                  np.linalg.norm(a_) / np.linalg.norm(b_) - 1,
                  np.linalg.norm(a_ - b_) / np.linalg.norm(b_)]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="../shared/data/kitti_raw_0926_41s")
    ap.add_argument("--shift-ms", default="-40:41:5", help="image-stamp shifts A:B:STEP (ms)")
    ap.add_argument("--calib", default=None, help="Kalibr camchain replacing the calibration")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    ds = load_dataset(args.dataset)
    if args.calib is not None:
        from svains.datasets.kalibr import apply_kalibr

        ds = apply_kalibr(ds, args.calib)
    pairs = stereo_pairs(ds)
    t_ns = pairs[0]
    disparity: dict[int, float] = {}
    prev: dict[int, int] = {}
    index_of = {int(t): i for i, t in enumerate(t_ns)}

    def on_frame(i, tracks, fe):  # type: ignore[no-untyped-def]
        if tracks is not None and tracks.inlier.any():
            d = tracks.uv_left_prev[tracks.inlier, 0] - tracks.uv_right_prev[tracks.inlier, 0]
            disparity[i] = float(np.median(d))
            prev[i] = index_of[int(tracks.t_prev_ns)]
        rig_box.append(fe.rig)

    rig_box: list = []
    run = run_frontend(ds, pairs, on_frame=on_frame)
    rig = rig_box[0]
    ego = [r.egomotion for r in run.records]
    prev_idx = [prev.get(i, -1) for i in range(len(ego))]
    E = step_errors(ds, t_ns, rig, ego, prev_idx)
    ok = np.isfinite(E[:, 0]) & (E[:, 4] > 0.5)
    s, v, h, rel = E[ok, 0], E[ok, 1], E[ok, 2], E[ok, 3]
    q = lambda x: np.percentile(x, [25, 50, 75])  # noqa: E731
    print(f"{ok.sum()} steps > 0.5 m; median relative step error {np.median(rel) * 100:.2f} %")
    print(f"scale |t_est|/|t_ref|: quartiles {q(s)}, robust std {robust_std(s):.4f}")
    print(f"vertical tilt (deg): quartiles {q(v)}; horizontal: {q(h)}")
    se = s - np.median(s)
    print(f"lag-1 correlation of scale errors: {np.corrcoef(se[:-1], se[1:])[0, 1]:+.3f}")
    # Error budget: relative error with the scale set to the reference's, or the direction.
    dirn_only = np.hypot(np.radians(v - np.median(v)), np.radians(h - np.median(h)))
    print(f"median |scale - 1| {np.median(np.abs(s - 1)) * 100:.2f} %, median direction error "
          f"(tilt removed) {np.median(dirn_only) * 100:.2f} % of the step, with tilt "
          f"{np.median(np.hypot(np.radians(v), np.radians(h))) * 100:.2f} %")
    dt = np.diff(t_ns) * 1e-9
    speed = E[ok, 4] / np.median(dt)
    print(f"frame interval: median {np.median(dt) * 1e3:.1f} ms, robust std "
          f"{robust_std(dt) * 1e3:.2f} ms; speed median {np.median(speed):.1f} m/s")
    disp = np.array([disparity.get(i, np.nan) for i in range(len(ego))])[ok]
    for lo, hi in [(0, 15), (15, 25), (25, 40), (40, 1e9)]:
        m = (disp >= lo) & (disp < hi)
        if m.sum():
            print(f"median inlier disparity {lo}-{hi} px: {m.sum()} steps, scale median "
                  f"{np.median(s[m]):.4f}, rel error {np.median(rel[m]) * 100:.2f} %")
    cov_dir = np.array([predicted_direction_std(e) for e in ego])[ok]
    print(f"front end's own covariance: median predicted direction std (per axis) "
          f"{np.degrees(np.median(cov_dir)):.3f} deg; observed robust std vertical "
          f"{robust_std(v):.3f} deg, horizontal {robust_std(h):.3f} deg")
    R = reference_consistency(ds, t_ns, prev_idx, rig)[ok]
    print(f"reference position vs its integrated velocity over each step (camera axes): robust "
          f"std vertical {robust_std(R[:, 0]):.3f} deg, horizontal {robust_std(R[:, 1]):.3f} "
          f"deg, length {robust_std(R[:, 2]) * 100:.2f} %; median tilt v {np.median(R[:, 0]):+.3f} "
          f"h {np.median(R[:, 1]):+.3f} deg; median relative difference "
          f"{np.median(R[:, 3]) * 100:.2f} % ({np.median(R[:, 3]) * 100:.2f} % is the "
          f"reference's own floor on the step error)")
    a, b, st = (float(x) for x in args.shift_ms.split(":"))
    for tau in np.arange(a, b, st):
        Et = step_errors(ds, t_ns, rig, ego, prev_idx, int(tau * 1e6))
        okt = np.isfinite(Et[:, 0]) & (Et[:, 4] > 0.5)
        print(f"shift {tau:+5.0f} ms: rel error {np.median(Et[okt, 3]) * 100:.2f} %, scale "
              f"{np.median(Et[okt, 0]):.4f}, tilt v {np.median(Et[okt, 1]):+.3f} h "
              f"{np.median(Et[okt, 2]):+.3f}")


if __name__ == "__main__":
    main()
