"""Front end on simulated village images: egomotion error, moving-object rejection, depth error.

Simulates the default village flight (2 Hz stereo images) with the moving crate switched on,
runs the sparse front end, and measures against the simulator's exact world:

- frame-to-frame egomotion error against the true camera poses (median translation, rotation);
- features whose pixel at k-1 sees the moving crate first (ray cast into the world's solids):
  the fraction flagged as outliers;
- depth of static inlier features vs the ray-cast truth, binned by depth, against the stereo
  error model ``σ_z = z² σ_d / (f b)``: the implied disparity noise ``σ_d`` per bin should be the
  same in every bin if the model holds.

Usage: ``python bench/eval_frontend_sim.py [DURATION_S] [OUT_DIR]`` (default 110 s, a temp dir).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from svains.datasets import load_dataset, stereo_pairs
from svains.frontend.run import run_frontend, summarize
from svains.frontend.types import StereoTracks
from svains.sim.config import SimConfig
from svains.sim.simulate import build_scene, simulate
from svains.sim.world import World


def first_hit(
    world: World, t_s: float, o_W: np.ndarray, d_W: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter of the first surface hit (N,) (inf: sky) and the solid index hit (N,)
    (-1: ground or sky) for rays ``o_W + t d_W``, solids placed at time ``t_s``."""
    n, d = world.planes_at(t_s)  # (M, P, 3), (M, P)
    den = np.einsum("mpk,nk->nmp", n, d_W)
    num = d[None] - np.einsum("mpk,k->mp", n, o_W)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = num / den
    enter = np.where(den < 0, tt, -np.inf).max(axis=2)
    leave = np.where(den > 0, tt, np.inf).min(axis=2)
    parallel_out = np.any((den == 0) & (num < 0), axis=2)
    hit = (enter <= leave) & (leave > 0) & ~parallel_out
    t_solid = np.where(hit, np.maximum(enter, 0.0), np.inf)
    best = np.argmin(t_solid, axis=1)
    t_best = t_solid[np.arange(len(best)), best]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d_W[:, 2] < 0, (world.ground_height - o_W[2]) / d_W[:, 2], np.inf)
    solid = np.where(t_best < t_ground, best, -1)
    return np.minimum(t_best, t_ground), solid


def main() -> int:
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else 110.0
    if len(sys.argv) > 2:
        return evaluate(duration, Path(sys.argv[2]))
    with tempfile.TemporaryDirectory(prefix="svains_sim_") as tmp:
        return evaluate(duration, Path(tmp))


def evaluate(duration: float, out: Path) -> int:
    """Simulate into ``out`` (unless a data set is already there) and print the measurements."""
    cfg = SimConfig()
    cfg.duration_s = duration
    cfg.world.moving_object = True
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
    z_est: list[np.ndarray] = []
    z_true: list[np.ndarray] = []
    for tr in collected:
        i = index_of[tr.t_prev_ns]
        R_W_C, p_W_C = T[i, :3, :3], T[i, :3, 3]
        ray_C = np.c_[(tr.uv_left_prev - [rig.cu, rig.cv]) / rig.f, np.ones(len(tr.inlier))]
        t_hit, solid = first_hit(world, tr.t_prev_ns * 1e-9, p_W_C, ray_C @ R_W_C.T)
        mov = np.isin(solid, moving_solids)
        on_moving += int(mov.sum())
        flagged += int((mov & ~tr.inlier).sum())
        if mov.any():
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
    print(f"village 2 Hz, {rep['frames']} frames, moving crate on; sparse front end")
    print(f"inliers per frame median {rep['inliers_median']}, min {rep['inliers_min']}")
    print(f"egomotion translation error median {rep['egomotion_translation_error_median_m']:.4f} m"
          f" (step median {rep['egomotion_translation_median_m']:.3f} m), rotation error median "
          f"{rep['egomotion_rotation_error_median_deg']:.4f} deg")  # fmt: skip
    frac = flagged / on_moving if on_moving else float("nan")
    print(f"features on the moving crate: {on_moving}, flagged outliers: {flagged} ({frac:.1%})")
    frac_big = big_flagged / big_moving if big_moving else float("nan")
    print(f"  of which the crate's own motion shifts > 3 px (2x the inlier threshold): "
          f"{big_moving}, flagged: {big_flagged} ({frac_big:.1%})")  # fmt: skip
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
