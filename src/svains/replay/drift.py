"""Free-inertial drift: restart from ground truth every window, measure the error at its end."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svains.datasets.types import Dataset
from svains.errors import InitialisationError
from svains.models.state import BIASED, PAPER
from svains.navigation.ins import InsFilter
from svains.navigation.options import FilterOptions, InitOptions, NoiseOptions, RunConfig
from svains.replay.groundtruth import interpolate_groundtruth, navigation_errors
from svains.replay.replay import groundtruth_start, history_from_dataset, rig_from_dataset


@dataclass(frozen=True)
class DriftWindow:
    """Error (truth − estimate) after ``duration_s`` of IMU-only propagation from ``t0_ns``."""

    t0_ns: int
    duration_s: float
    position_error_m: float
    velocity_error_mps: float
    attitude_error_deg: float


def drift_windows(
    dataset: Dataset,
    model: str = "biased",
    window_s: float = 5.0,
    filter_options: FilterOptions | None = None,
    noise_options: NoiseOptions | None = None,
) -> list[DriftWindow]:
    """One IMU-only run per consecutive ``window_s`` window of the ground truth's span."""
    gt = dataset.groundtruth
    if gt is None or dataset.imu is None:
        raise InitialisationError("drift windows need an IMU stream and ground truth")
    layout = BIASED if model == "biased" else PAPER
    rig = rig_from_dataset(dataset)
    history = history_from_dataset(dataset)
    config = RunConfig(model=model, init=InitOptions(mode="groundtruth"))  # type: ignore[arg-type]
    out: list[DriftWindow] = []
    w_ns = int(window_s * 1e9)
    t_last = min(int(gt.t_ns[-1]), int(dataset.imu.t_ns[-1]))
    for t0 in range(int(gt.t_ns[0]), t_last - w_ns + 1, w_ns):
        init = groundtruth_start(dataset, config, t0)
        ins = InsFilter(
            history,
            rig,
            layout,
            init,
            filter_options or FilterOptions(),
            noise_options or NoiseOptions(),
        )
        t1 = init.t_ns + w_ns
        if t1 > min(ins.t_end_ns, int(gt.t_ns[-1])):
            break
        ins.propagate_to(t1)
        _, p, v, q = interpolate_groundtruth(gt, np.array([t1]))
        e = navigation_errors(ins.ukf.x[None], p, v, q)[0]
        out.append(
            DriftWindow(
                init.t_ns,
                window_s,
                float(np.linalg.norm(e[0:3])),
                float(np.linalg.norm(e[3:6])),
                float(np.degrees(np.linalg.norm(e[6:9]))),
            )
        )
    return out
