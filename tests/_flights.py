"""Simulated flights the tests share: the village, recorded features only (no images), GPS at
1 Hz throughout (no outages)."""

from __future__ import annotations

from pathlib import Path


def gps_flight(folder: Path, duration_s: float, seed: int, camera_hz: float | None = None) -> Path:
    """The village flight of ``duration_s`` (s) and ``seed`` written to ``folder``: its root
    (recorded features at ``camera_hz``, None: the simulator's rate)."""
    from svains.sim import SimConfig, simulate

    cfg = SimConfig(duration_s=duration_s, seed=seed)
    cfg.camera.render_images = False
    if camera_hz is not None:
        cfg.camera.rate_hz = camera_hz
    cfg.gps.outages = []
    return simulate(cfg, folder)
