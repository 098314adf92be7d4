"""What forward-backward smoothing costs (issue 25): forward wall time with and without the
recorder, the backward pass's wall time, and the history kept per hour of data.

Each case is replayed ``--repeats`` times alternately with ``smoother.enabled`` off and on (the
medians are compared); the smoothing pass is ``navigation.smoothing.smoothed_result``.

    python bench/smoother_cost.py [--cases sim-ins,sim-3d,kitti-3d] [--repeats 3]

Cases: ``sim-ins``, ``sim-lc``, ``sim-3d``: a 60 s village flight (seed 0, features at 5 Hz,
GPS with the village's outages, start from the true pose); ``kitti-ins``, ``kitti-3d``: KITTI
raw with GPS lost 10-20 s and 25-35 s, in-flight start, images (the README's outage command).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from svains.cli.run_config import build_config
from svains.datasets.loader import load_dataset
from svains.datasets.types import Dataset
from svains.navigation.options import RunConfig, SmootherOptions
from svains.navigation.smoothing import smoothed_result
from svains.replay import replay, resolve_config
from svains.sim import SimConfig, simulate

KITTI = Path(__file__).resolve().parents[1].parent / "shared/data/kitti_raw_0926_41s"


def _case(name: str, tmp: Path) -> tuple[Dataset, RunConfig]:
    source, method = name.split("-")
    if source == "sim":
        cfg = SimConfig()
        cfg = replace(cfg, duration_s=60.0, seed=0,
                      camera=replace(cfg.camera, rate_hz=5.0, render_images=False))  # fmt: skip
        ds = load_dataset(simulate(cfg, tmp / "sim", overwrite=True))
        config = build_config(None, [], {"method": method, "init.mode": "groundtruth",
                                         "vision.source": "features"})  # fmt: skip
        return ds, config
    config = build_config(None, [], {"method": method, "init.mode": "gps", "use_mag": False,
                                     "vision.source": "images",
                                     "gps_outages": ((10.0, 10.0), (25.0, 10.0))})  # fmt: skip
    return load_dataset(KITTI), config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="sim-ins,sim-lc,sim-3d,kitti-ins,kitti-3d")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    print("| case | forward [s] | forward recording [s] | overhead | smoothing pass [s] | "
          "pass / forward | total / forward | history [MB per hour] |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.cases.split(","):
            ds, config = _case(name, Path(tmp))
            config = resolve_config(ds, config)
            on = replace(config, smoother=SmootherOptions(enabled=True))
            walls: dict[bool, list[float]] = {False: [], True: []}
            passes = []
            for _ in range(args.repeats):
                for record in (False, True):
                    t0 = time.perf_counter()
                    res = replay(ds, on if record else config)
                    walls[record].append(time.perf_counter() - t0)
                    if record:
                        t1 = time.perf_counter()
                        sm = smoothed_result(res)
                        passes.append(time.perf_counter() - t1)
                        mb_h = sm.report["smoothing"]["history_mb_per_hour"]
            off, rec, sp = (statistics.median(walls[False]), statistics.median(walls[True]),
                            statistics.median(passes))  # fmt: skip
            print(f"| {name} | {off:.2f} | {rec:.2f} | {100 * (rec / off - 1):+.1f} % | {sp:.3f} | "
                  f"{100 * sp / off:.1f} % | {100 * (rec + sp - off) / off:+.1f} % | {mb_h:.1f} |",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
