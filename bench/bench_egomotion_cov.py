"""Cost of the four-pixel egomotion covariance (``svains.frontend.egomotion_cov``).

One synthetic frame of M features (depths 2-40 m, 0.1 px noise as the image front end, or
0.5 px as ``features0`` where the inlier gate is active), the covariance computed as
``estimate_egomotion`` calls it; prints the mean time per call.

    python bench/bench_egomotion_cov.py
"""

from __future__ import annotations

import time

import numpy as np

from svains.frontend.egomotion_cov import egomotion_covariance
from svains.geometry.camera import RectifiedStereo
from svains.geometry.rotation import so3_exp

RIG = RectifiedStereo(458.654, 367.215, 248.375, 0.11, np.eye(3), np.zeros(3), 752, 480)


def frame(m: int, sigma_px: float, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    u, v, z = rng.uniform(20, 732, m), rng.uniform(20, 460, m), rng.uniform(2.0, 40.0, m)
    P = np.c_[(u - RIG.cu) * z / RIG.f, (v - RIG.cv) * z / RIG.f, z]
    R, t = so3_exp(np.array([0.01, 0.02, 0.0])), np.array([0.1, 0.0, 0.3])
    Q = P @ R.T + t

    def noisy(a: np.ndarray) -> np.ndarray:
        return a + rng.normal(0.0, sigma_px, a.shape)

    p_prev = RIG.triangulate(noisy(RIG.project(P)), noisy(RIG.project_right(P)))
    return R, t, p_prev, noisy(RIG.project(Q)), noisy(RIG.project_right(Q))


def main() -> None:
    for m, sigma in ((250, 0.1), (250, 0.5), (800, 0.5)):
        R, t, p, uvl, uvr = frame(m, sigma)
        dv = 2.0 * (p[:, 2] ** 2 / (RIG.f * RIG.baseline)) ** 2
        kw = dict(robust=True, inflation=13.0, estimator_depth_var_px2=dv, gate_px=1.5)
        for _ in range(10):
            egomotion_covariance(R, t, p, uvl, uvr, RIG, 0.1, **kw)
        n = 200
        t0 = time.perf_counter()
        for _ in range(n):
            egomotion_covariance(R, t, p, uvl, uvr, RIG, 0.1, **kw)
        ms = (time.perf_counter() - t0) / n * 1e3
        print(f"egomotion covariance, {m} features, {sigma} px noise: {ms:.3f} ms per frame")


if __name__ == "__main__":
    from svains.threads import limit_threads

    with limit_threads(None):  # SVAINS_THREADS, default one thread per library
        main()
