"""How the ``3d`` filter's pixel-noise inflation and feature count trade accuracy and consistency.

The campaign is ``bench/specs/tc_noise_scan.yaml`` (``svains batch`` runs it alone; its
``summary.md`` has the means per variant): the 60 s GPS-denied, magnetometer-free village
flights of ``bench/paper_ordering.py`` (feature level, stereo 5 Hz), ``3d`` with the default
vision options and with ``pixel_noise_scale`` 1.0 / 1.4, all features instead of
``max_features=120``, both, and (all features) the inter-frame gyro noise modelled as a
feature-correlated term instead of a per-frame gyro-bias walk, or not modelled. This script runs
it through the batch library and prints ATE (posyaw) m / final error % of path / mean NEES
(9 dof) per seed and variant.

    python bench/tc_noise_scan.py [SEED ...]   (default seeds 0 1 2)
"""

from __future__ import annotations

import logging
import sys

import yaml
from paper_ordering import HERE, campaign_rows, value  # same runs as the ordering bench


def main() -> int:
    logging.basicConfig(level=logging.ERROR)
    raw = yaml.safe_load((HERE / "specs" / "tc_noise_scan.yaml").read_text(encoding="utf-8"))
    if sys.argv[1:]:
        raw["seeds"] = [int(a) for a in sys.argv[1:]]
    rows = campaign_rows(raw, None)
    for seed in raw["seeds"]:
        cells = []
        for name in raw["configs"]:
            r = rows[seed, name, "3d"]
            ate, final = value(r, "ate_m"), value(r, "final_error_pct_of_path")
            cells.append(f"{name} {ate:.3f}/{final:.2f}%/nees {value(r, 'nees_mean'):.1f}")
        print(f"seed {seed}: " + " | ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
