"""Front end on simulated village images: egomotion error, moving-object rejection, depth error.

Simulates the default village flight (2 Hz stereo images) with the moving object (a
vehicle-sized box with a non-periodic clutter texture, walking back and forth at ~1 m/s across
the view of one leg) switched on, runs the sparse front end without any motion prior, and
measures against the simulator's exact world:

- frame-to-frame egomotion error against the true camera poses (median translation, rotation);
- features whose pixel at k-1 sees the moving crate first (ray cast into the world's solids):
  the fraction flagged as outliers;
- depth of static inlier features vs the ray-cast truth, binned by depth, against the stereo
  error model ``σ_z = z² σ_d / (f b)``: the implied disparity noise ``σ_d`` per bin should be the
  same in every bin if the model holds.

Then the same flight without the object (same village otherwise), for the egomotion error.

Both runs also check the egomotion covariance (``svains.frontend.egomotion_cov``): the NEES of
the true frame-to-frame motion error against ``Egomotion.cov`` (mean, median, per axis; 6, 3,
1 if consistent) and the pixel noise the four-pixel model implies at the true motion (robust
whitened residual of the inliers), i.e. the measured KLT/stereo error to set
``RansacOptions.pixel_sigma_px`` from.

Usage: ``python bench/eval_frontend_sim.py [DURATION_S] [OUT_DIR] [SEED]`` (default 110 s, a temp
dir, seed 0; seed 1 puts the object nearer the leg's end, larger in the images;
an existing data set in ``OUT_DIR/with_object`` or ``OUT_DIR/without_object`` is reused).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset, stereo_pairs
from svains.frontend.egomotion_cov import whitened_residuals
from svains.frontend.run import run_frontend, summarize
from svains.frontend.types import StereoTracks
from svains.geometry.rotation import so3_log
from svains.sim.config import SimConfig
from svains.sim.simulate import build_scene, simulate

WALK_SPEED = 1.0  # m/s: the object's mean speed (period = 4 amplitude / speed)


def main() -> int:
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else 110.0
    seed = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    if len(sys.argv) > 2 and sys.argv[2] != "-":
        return run_both(duration, Path(sys.argv[2]), seed)
    with tempfile.TemporaryDirectory(prefix="svains_sim_") as tmp:
        return run_both(duration, Path(tmp), seed)


def run_both(duration: float, out: Path, seed: int = 0) -> int:
    """With the moving object (all measurements), then without it (egomotion error only)."""
    seen = evaluate(duration, out / "with_object", moving=True, seed=seed)
    print()
    evaluate(duration, out / "without_object", moving=False, frames_of_interest=seen, seed=seed)
    return 0


def evaluate(
    duration: float, out: Path, moving: bool = True, frames_of_interest: list[int] | None = None,
    seed: int = 0,
) -> list[int]:
    """Simulate into ``out`` (unless a data set is already there) and print the measurements.

    Returns the indices of the frames whose tracks saw the moving object; the egomotion error is
    also reported over ``frames_of_interest`` (those frames, from the run with the object)."""
    cfg = SimConfig()
    cfg.duration_s = duration
    cfg.seed = seed
    cfg.world.moving_object = moving
    cfg.world.moving_period_s = 4.0 * cfg.world.moving_amplitude / WALK_SPEED
    if not (out / "mav0").is_dir():
        simulate(cfg, out)
    scene = build_scene(cfg)
    world = scene.world
    moving_solids = [k for k, s in enumerate(world.solids) if s.moving]
    ds = load_dataset(out)
    pairs = stereo_pairs(ds)
    collected: list[StereoTracks] = []
    run = run_frontend(ds, pairs, on_frame=lambda i, tr, fe: collected.append(tr) if tr else None)
    rep = summarize(run)
    rig = scene.rig
    T = run.T_W_C_gt
    assert T is not None
    index_of = {int(t): i for i, t in enumerate(pairs[0])}
    on_moving = flagged = 0
    big_moving = big_flagged = 0  # object's own motion shifts its pixels by > 3 px
    seen: list[int] = []
    z_est: list[np.ndarray] = []
    z_true: list[np.ndarray] = []
    for tr in collected:
        i = index_of[tr.t_prev_ns]
        R_W_C, p_W_C = T[i, :3, :3], T[i, :3, 3]
        ray_C = np.c_[(tr.uv_left_prev - [rig.cu, rig.cv]) / rig.f, np.ones(len(tr.inlier))]
        t_hit, solid = world.first_hit(tr.t_prev_ns * 1e-9, p_W_C, ray_C @ R_W_C.T)
        mov = np.isin(solid, moving_solids)
        on_moving += int(mov.sum())
        flagged += int((mov & ~tr.inlier).sum())
        if mov.any():
            seen.append(index_of[tr.t_ns])
            # Pixel shift at k caused by the object's own displacement between k-1 and k.
            j = index_of[tr.t_ns]
            t0_s, t1_s = tr.t_prev_ns * 1e-9, tr.t_ns * 1e-9
            shift_W = world.moving_offset_W(t1_s) - world.moving_offset_W(t0_s)
            p_W = p_W_C + t_hit[mov, None] * (ray_C[mov] @ R_W_C.T)
            R_C_W, p_C_W = T[j, :3, :3].T, -T[j, :3, :3].T @ T[j, :3, 3]
            uv_static = rig.project(p_W @ R_C_W.T + p_C_W)
            uv_moved = rig.project((p_W + shift_W) @ R_C_W.T + p_C_W)
            big = np.linalg.norm(uv_moved - uv_static, axis=1) > 3.0
            big_moving += int(big.sum())
            big_flagged += int((big & ~tr.inlier[mov]).sum())
        keep = tr.inlier & ~mov & np.isfinite(t_hit)
        z_est.append(tr.p_Ckm1_F[keep, 2])
        z_true.append(t_hit[keep])  # ray z-component is 1: t is the depth
    ze, zt = np.concatenate(z_est), np.concatenate(z_true)
    what = f"moving object on ({WALK_SPEED:.1f} m/s)" if moving else "no moving object"
    print(f"village 2 Hz seed {seed}, {rep['frames']} frames, {what}; sparse front end, "
          "no motion prior")
    print(f"inliers per frame median {rep['inliers_median']}, min {rep['inliers_min']}")
    print(f"egomotion translation error median {rep['egomotion_translation_error_median_m']:.4f} m"
          f" (step median {rep['egomotion_translation_median_m']:.3f} m), rotation error median "
          f"{rep['egomotion_rotation_error_median_deg']:.4f} deg")  # fmt: skip
    sub = seen if moving else (frames_of_interest or [])
    if sub:
        e_t = [run.records[j].translation_error_m for j in sub]
        e_r = [run.records[j].rotation_error_deg for j in sub]
        print(f"  over the {len(sub)} frames that see the moving object: translation error median "
              f"{np.nanmedian(e_t):.4f} m, max {np.nanmax(e_t):.4f} m; rotation error median "
              f"{np.nanmedian(e_r):.4f} deg, max {np.nanmax(e_r):.4f} deg")  # fmt: skip
    if moving:
        frac = flagged / on_moving if on_moving else float("nan")
        print(f"features on the moving object: {on_moving}, flagged outliers: {flagged} "
              f"({frac:.1%})")  # fmt: skip
        frac_big = big_flagged / big_moving if big_moving else float("nan")
        print(f"  of which the object's own motion shifts > 3 px (2x the inlier threshold): "
              f"{big_moving}, flagged: {big_flagged} ({frac_big:.1%})")  # fmt: skip
    report_covariance(collected, T, index_of, rig)
    err = ze - zt
    print(f"depth error of {err.size} static inliers vs stereo model sigma_z = z^2 sigma_d/(f b):")
    print(f"{'depth bin [m]':>14} {'n':>6} {'median err [m]':>15} {'rms err [m]':>12} "
          f"{'implied sigma_d [px]':>21}")  # fmt: skip
    fb = rig.f * rig.baseline
    for lo, hi in ((0, 4), (4, 8), (8, 12), (12, 20), (20, 40)):
        m = (zt >= lo) & (zt < hi) & (np.abs(err) < 0.5 * zt)  # drop gross mismatches
        if m.sum() < 10:
            continue
        # Robust spread: 1.4826 * MAD, then the disparity noise the model needs to explain it.
        spread = 1.4826 * np.median(np.abs(err[m] - np.median(err[m])))
        sigma_d = spread * fb / np.median(zt[m] ** 2)
        print(f"{lo:>6}-{hi:<7} {int(m.sum()):>6} {np.median(err[m]):>15.3f} "
              f"{np.sqrt(np.mean(err[m] ** 2)):>12.3f} {sigma_d:>21.3f}")  # fmt: skip
    return seen


def report_covariance(
    collected: list[StereoTracks], T_W_C: np.ndarray, index_of: dict[int, int], rig: object
) -> None:
    """NEES of the true egomotion error against the front end's covariance, and the pixel noise
    implied by the inliers' residuals at the true motion."""
    nees, per_axis, w2 = [], [], []
    for tr in collected:
        if tr.egomotion is None:
            continue
        T_rel = np.linalg.inv(T_W_C[index_of[tr.t_ns]]) @ T_W_C[index_of[tr.t_prev_ns]]
        R_true, p_true = T_rel[:3, :3], T_rel[:3, 3]
        ego = tr.egomotion
        e = np.r_[so3_log(ego.R_Ck_Ckm1.T @ R_true), p_true - ego.p_Ck_Ckm1]
        nees.append(float(e @ np.linalg.solve(ego.cov, e)))
        per_axis.append(e * e / np.diag(ego.cov))
        m = tr.inlier
        w2.append(whitened_residuals(R_true, p_true, tr.p_Ckm1_F[m], tr.uv_left[m],
                                     tr.uv_right[m], rig))  # type: ignore[arg-type]
    if not nees:
        return
    n = np.array(nees)
    ax = np.mean(per_axis, axis=0)
    print(f"egomotion NEES over {n.size} frames (6 if consistent): mean {n.mean():.2f}, median "
          f"{np.median(n):.2f} (chi2(6) median 5.35); per axis (rx ry rz tx ty tz) "
          + " ".join(f"{v:.2f}" for v in ax))  # fmt: skip
    w = np.concatenate(w2)
    w = w[np.isfinite(w)]
    print(f"pixel noise implied at the true motion (four-pixel model, {w.size} inlier "
          f"residuals): sigma = {np.sqrt(np.median(w) / 3.356694):.3f} px (robust)")  # fmt: skip


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        sys.exit(main())
