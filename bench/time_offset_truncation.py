"""Why the time offset moves poses through the IMU samples, not to first order only.

On the simulator's true village trajectory, the camera motion between consecutive frames
captured at ``t + t_d`` is predicted from the true states at the stamps ``t`` moved by a trial
offset to first order (``p + v t_d``, ``R Exp(ω t_d)``) or to second order (plus ``½ a t_d²``,
``½ α t_d²``); the trial offset that best explains the true motion (least squares over a 0.5 ms
grid, rotation in rad and translation weighted 0.2 /m) is printed. A first-order model that
needs a different offset than the truth biases any filter that uses it.

    python bench/time_offset_truncation.py [--offset-ms 50] [--rate 20] [--vibration-deg 0.3]
"""

from __future__ import annotations

import argparse

import numpy as np

from svains.geometry.rotation import so3_exp, so3_log
from svains.sim.config import SimConfig
from svains.sim.simulate import build_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--offset-ms", type=float, default=50.0)
    ap.add_argument("--rate", type=float, default=20.0, help="stereo rate, Hz")
    ap.add_argument("--vibration-deg", type=float, default=0.3)
    args = ap.parse_args()
    td = args.offset_ms * 1e-3
    cfg = SimConfig.from_dict({"duration_s": 60.0, "seed": 1,
                               "trajectory": {"vibration_deg": args.vibration_deg}})
    scene = build_scene(cfg)
    t = np.arange(0.2, 59.0, 1.0 / args.rate)
    stamp, capture = scene.trajectory.evaluate(t), scene.trajectory.evaluate(t + td)
    C, c = scene.rig.R_B_C, scene.rig.p_B_C

    def camera_motion(R1: np.ndarray, p1: np.ndarray, R2: np.ndarray, p2: np.ndarray) -> tuple[
        np.ndarray, np.ndarray
    ]:
        Rc1, pc1, Rc2, pc2 = R1 @ C, p1 + R1 @ c, R2 @ C, p2 + R2 @ c
        return Rc2.T @ Rc1, Rc2.T @ (pc1 - pc2)

    def moved(k: int, trial: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        th = stamp.omega_B[k] * trial
        p = stamp.p_W_B[k] + stamp.v_W_B[k] * trial
        if order >= 2:
            th = th + 0.5 * stamp.alpha_B[k] * trial**2
            p = p + 0.5 * stamp.a_W[k] * trial**2
        return stamp.R_W_B[k] @ so3_exp(th), p

    def cost(trial: float, order: int) -> float:
        total = 0.0
        for k in range(1, t.size):
            Rt, rt = camera_motion(capture.R_W_B[k - 1], capture.p_W_B[k - 1],
                                   capture.R_W_B[k], capture.p_W_B[k])  # fmt: skip
            Rm, rm = camera_motion(*moved(k - 1, trial, order), *moved(k, trial, order))
            total += float(np.sum(so3_log(Rm.T @ Rt) ** 2) + np.sum((0.2 * (rm - rt)) ** 2))
        return total

    grid = np.arange(0.0, 1.2 * td + 1e-12, 5e-4) if td > 0 else np.arange(1.2 * td, 1e-12, 5e-4)
    for order in (1, 2):
        costs = [cost(g, order) for g in grid]
        best = grid[int(np.argmin(costs))]
        print(f"order {order}: the best trial offset is {best * 1e3:.1f} ms for a true "
              f"{args.offset_ms:g} ms ({args.rate:g} Hz frames, vibration "
              f"{args.vibration_deg:g} deg)")


if __name__ == "__main__":
    main()
