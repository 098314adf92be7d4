"""How the ``3d`` filter's pixel-noise inflation and feature count trade accuracy and consistency.

Per seed: a 60 s GPS-denied, magnetometer-free village flight (feature-level simulation, stereo
5 Hz, as ``bench/paper_ordering.py``), then ``3d`` with the ``imu`` motion model and with
``pixel_noise_scale`` 1.0 / 1.4, all features instead of ``max_features=120``, both, and (all
features) the inter-frame gyro noise modelled as a feature-correlated term instead of a
per-frame gyro-bias walk, or not modelled; then with pose clones (the default) and without
their far-feature gate, without single-use pixels, or with all features. Prints ATE (posyaw)
m / final error % of path / mean NEES (9 dof) per variant.

    python bench/tc_noise_scan.py [SEED ...]   (default seeds 0 1 2)
"""

from __future__ import annotations

import logging
import sys
import tempfile
from pathlib import Path

from paper_ordering import denied_options, denied_village  # same runs as the ordering bench

from svains.evaluation.compare import run_methods

_IMU = {"rotation": "imu"}
VARIANTS: dict[str, dict[str, object]] = {
    "imu": _IMU,
    "imu_scale1": {**_IMU, "pixel_noise_scale": 1.0},
    "imu_scale1.4": {**_IMU, "pixel_noise_scale": 1.4},
    "imu_all_feats": {**_IMU, "max_features": None},
    "imu_scale1.4_all": {**_IMU, "pixel_noise_scale": 1.4, "max_features": None},
    # The gyro noise integrated between frames, shared by all features of a frame: modelled as a
    # feature-correlated noise term instead of the per-frame bias walk, or not at all.
    "imu_G_term_all": {**_IMU, "max_features": None, "frame_gyro_walk": False},
    "imu_no_imu_noise_all": {**_IMU, "max_features": None, "frame_gyro_walk": False,
                             "imu_noise": False},
    # Pose clones (the default): true pixel noise; without the far-feature gate; without
    # single-use pixels; all features.
    "clone": {},
    "clone_no_gate": {"min_disparity_px": 0.0},
    "clone_reuse_pixels": {"single_use_pixels": False},
    "clone_all_feats": {"max_features": None},
}


def main() -> int:
    logging.basicConfig(level=logging.ERROR)
    seeds = [int(a) for a in sys.argv[1:]] or [0, 1, 2]
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            ds = denied_village(seed, 60.0, 5.0, Path(tmp) / f"s{seed}")
            row = []
            for name, extra in VARIANTS.items():
                r = run_methods(ds, ("3d",), denied_options(**extra), None)["3d"].report
                row.append(f"{name} {r['ate_m']:.3f}/{r['final_error_pct_of_path']:.2f}%/"
                           f"nees {r.get('nees_mean', float('nan')):.1f}")  # fmt: skip
            print(f"seed {seed}: " + " | ".join(row), flush=True)
    return 0


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        sys.exit(main())
