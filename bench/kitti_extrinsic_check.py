"""Is the camera-IMU rotation of a real data set consistent with its reference trajectory?

Compares the direction of the front end's stereo translation between frames (``Egomotion``)
with the reference's camera displacement expressed through the calibrated ``R_B_C``: a median
tilt that is not zero is a rotation error of the camera-IMU calibration (or of the
rectification), which no filter without an online extrinsic state can remove. With
``--correct`` the tilt is removed from both cameras' ``T_B_C`` (fitted on the ground truth: a
diagnostic, not a calibration) and ``3d`` runs GPS-denied from the reference start. With
``--from-gps`` the rotation is instead estimated online (``vision.estimate_extrinsics``) by a
``3d`` run WITH GPS (no ground truth involved, but note that a data set's GPS may be derived
from its reference, as KITTI raw's gps0 is), then applied and ``3d`` runs GPS-denied.

    python bench/kitti_extrinsic_check.py [DATASET] [--correct | --from-gps] [--set KEY=VALUE]
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace

import numpy as np

from svains.cli.run_config import build_config
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset
from svains.evaluation.extrinsics import corrected_calibration
from svains.evaluation.run import run_method
from svains.geometry.rotation import quat_to_rotmat, so3_exp
from svains.navigation.vision_sources import ImageFrames
from svains.replay.groundtruth import interpolate_groundtruth


def direction_tilt_deg(ds: Dataset) -> tuple[float, float, int]:
    """Median (vertical, horizontal) angle (deg) from the reference's to the front end's
    translation direction, left-camera axes (atan2(y, z), atan2(x, z)), and the frame count."""
    from svains.datasets.loader import stereo_pairs

    src = ImageFrames(ds.cam0, ds.cam1)
    R_B_C, c_B = np.asarray(src.rig.R_B_C), np.asarray(src.rig.p_B_C)
    rows = []
    times, il, ir = stereo_pairs(ds)
    for t, a, b in zip(times, il, ir, strict=True):
        src.push(int(t), ds.left.load(int(a)), ds.right.load(int(b)))  # type: ignore[union-attr]
        tr = src.tracks_at(int(t))
        if tr is None or tr.egomotion is None:
            continue
        _, p, _, q = interpolate_groundtruth(ds.groundtruth, np.array([tr.t_prev_ns, tr.t_ns]))
        R0, R1 = quat_to_rotmat(q[0]), quat_to_rotmat(q[1])
        d_ref = (R0 @ R_B_C).T @ (p[1] + R1 @ c_B - p[0] - R0 @ c_B)
        d_vis = -np.asarray(tr.egomotion.R_Ck_Ckm1).T @ np.asarray(tr.egomotion.p_Ck_Ckm1)
        if np.linalg.norm(d_ref) < 0.5:  # too short a step for a direction
            continue
        rows.append([np.arctan2(d_vis[1], d_vis[2]) - np.arctan2(d_ref[1], d_ref[2]),
                     np.arctan2(d_vis[0], d_vis[2]) - np.arctan2(d_ref[0], d_ref[2])])
    med = np.degrees(np.median(np.array(rows), axis=0))
    return float(med[0]), float(med[1]), len(rows)


def corrected(ds: Dataset, vertical_deg: float, horizontal_deg: float) -> Dataset:
    """``ds`` with both cameras turned by ``Rx(v) Ry(-h)`` (camera axes), which turns
    the reference's camera-frame directions onto the front end's."""
    delta = so3_exp(np.radians([vertical_deg, 0.0, 0.0])) @ so3_exp(
        np.radians([0.0, -horizontal_deg, 0.0]))

    def turn(cam):  # type: ignore[no-untyped-def]
        T = np.array(cam.T_B_C, dtype=float)
        T[:3, :3] = T[:3, :3] @ delta
        return replace(cam, T_B_C=T)

    return replace(ds, cam0=turn(ds.cam0), cam1=turn(ds.cam1))


def from_gps(ds: Dataset, sets: list[str], until_s: float | None = None) -> Dataset:
    """``ds`` with the camera rotation a ``3d`` run with GPS estimates online (over the first
    ``until_s`` seconds only, when given)."""
    opts = build_config(None, [*sets, "vision.estimate_extrinsics=true"], {
        "init.mode": "groundtruth", "use_gps": True, "use_mag": False,
        "vision.source": "images", "vision.rotation": "clone", "duration_s": until_s})
    vis = run_method(ds, "3d", opts).report["vision"]
    phi, std = vis["extrinsic_rotation_deg"], vis["extrinsic_rotation_std_deg"]
    print(f"estimated with GPS: correction {np.round(phi, 3)} deg (std {np.round(std, 3)})")
    return corrected_calibration(ds, np.radians(phi))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="../shared/data/kitti_raw_0926_41s")
    ap.add_argument("--correct", action="store_true")
    ap.add_argument("--from-gps", action="store_true")
    ap.add_argument("--held-out", type=float, default=None, metavar="S",
                    help="with --from-gps: calibrate on [0, S) s, run GPS-denied from S s on")
    ap.add_argument("--set", action="append", default=[], help="vision option KEY=VALUE")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    ds = load_dataset(args.dataset)
    v, h, n = direction_tilt_deg(ds)
    print(f"translation direction, front end minus reference: vertical {v:+.3f} deg, "
          f"horizontal {h:+.3f} deg (median of {n} frames)")
    if not (args.correct or args.from_gps):
        return
    ds_fixed = from_gps(ds, args.set, args.held_out) if args.from_gps else corrected(ds, v, h)
    v2, h2, _ = direction_tilt_deg(ds_fixed)
    print(f"after the correction: vertical {v2:+.3f} deg, horizontal {h2:+.3f} deg")
    start = {} if args.held_out is None else {"replay.start_s": args.held_out}
    opts = build_config(None, args.set, {"init.mode": "groundtruth", "use_gps": False,
                                         "vision.source": "images", "vision.rotation": "clone",
                                         **start})
    print(f"3d {opts.vision}")
    for name, d in (("as calibrated", ds), ("corrected", ds_fixed)):
        r = run_method(d, "3d", opts).report
        print(f"3d GPS-denied from {args.held_out or 0:.0f} s, {name}: final error "
              f"{r['final_error_pct']:.2f} % of {r['path_length_m']:.0f} m, NEES "
              f"{r['nees_mean']:.1f}, inside 3 sigma {r['position_within_3sigma']:.3f}")


if __name__ == "__main__":
    main()
