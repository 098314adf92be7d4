"""``svains simulate``: write a simulated ASL data set (the paper's village flight by default)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from svains.cli._common import (
    check_out_dir,
    fail,
    one_of,
    parse_outage,
    positive_finite,
    stereo_rate,
    stop_windows,
)
from svains.errors import SvainsError


def _flight_duration(value: float | None) -> float | None:
    """Typer callback: ``None`` or a finite duration in (0, MAX_DURATION_S] seconds."""
    from svains.sim.config import MAX_DURATION_S

    value = positive_finite(value)
    if value is not None and value > MAX_DURATION_S:
        raise typer.BadParameter(f"must be at most {MAX_DURATION_S:g} s, got {value:g}")
    return value


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate_cmd(
        out: Annotated[Path, typer.Option("--out", help="Output folder (the data set root; "
                                          "mav0/ is created inside).")],
        scenario: Annotated[str, typer.Option(
            "--scenario", help="'village': the paper's rectangle at 2 m altitude and 2 m/s "
            "through a textured village; 'trajectory': follow a TUM file (see --trajectory).",
            callback=one_of("village", "trajectory"),
        )] = "village",
        duration: Annotated[float | None, typer.Option(
            "--duration", help="Flight duration in seconds (default 110, or the config's; at "
            "most 3600).",
            callback=_flight_duration,
        )] = None,
        seed: Annotated[int | None, typer.Option(
            "--seed", help="Seed of every random draw (world layout, sensor noise).", min=0,
        )] = None,
        camera_rate: Annotated[float | None, typer.Option(
            "--camera-rate", help="Stereo frame rate in Hz, up to 20 (default 2, as the paper).",
            callback=stereo_rate,
        )] = None,
        no_images: Annotated[bool, typer.Option(
            "--no-images", help="Skip rendering: write only features0 (true landmark "
            "projections with pixel noise), so runs take seconds.",
        )] = False,
        config: Annotated[Path | None, typer.Option(
            "--config", help="YAML file with simulator settings (any subset of SimConfig: "
            "imu, gps, mag, sonar, camera, world, trajectory); options given here override it.",
        )] = None,
        trajectory: Annotated[Path | None, typer.Option(
            "--trajectory", help="TUM file (t x y z qx qy qz qw) to follow; implies "
            "--scenario trajectory.",
        )] = None,
        imu_preset: Annotated[str | None, typer.Option(
            "--imu-preset", help="'paper' (Table 1 noise, no bias drift) or 'adis16448' "
            "(EuRoC ADIS16448 noise and bias random walk).",
            callback=one_of("paper", "adis16448"),
        )] = None,
        stop: Annotated[list[str] | None, typer.Option(
            "--stop", help="START:DURATION \\[s]: the village vehicle halts at rest for DURATION "
            "from START, easing down and up over trajectory.stop_ramp_s; 0:D is a static "
            "start (with --imu-preset adis16448: the paper's IMU fails the rest test); "
            "repeatable.", callback=stop_windows,
        )] = None,
        force: Annotated[bool, typer.Option(
            "--force", help="Replace the data set already in --out (its mav0/).",
        )] = False,
    ) -> None:
        """Simulate IMU, GPS, magnetometer, sonar and a rendered stereo pair; write ASL.

        Writes imu0, cam0/cam1 (PNG), gps0, mag0, sonar0, features0 (true landmark tracks with
        pixel noise) and the ground truth at the IMU rate with kinematics.csv, landmarks.csv
        and scenario.yaml (the full configuration) beside it. The data set appears whole or
        not at all (written under a temporary name, then renamed), with the completion marker
        mav0/svains_complete.yaml.
        """
        from svains.sim.config import ImuConfig, SimConfig
        from svains.sim.simulate import simulate

        check_out_dir(out, force, replaced_whole=False)
        try:
            cfg = SimConfig.from_yaml(config) if config is not None else SimConfig()
            if trajectory is not None:
                cfg.scenario = "trajectory"
                cfg.trajectory.tum_path = str(trajectory)
            elif scenario != "village" or config is None:
                cfg.scenario = scenario
            if duration is not None:
                cfg.duration_s = duration
            if seed is not None:
                cfg.seed = seed
            if camera_rate is not None:
                cfg.camera.rate_hz = camera_rate
            if no_images:
                cfg.camera.render_images = False
            if imu_preset is not None:
                cfg.imu = ImuConfig.preset(imu_preset)
            if stop:
                cfg.trajectory.stops = [list(parse_outage(text, "--stop")) for text in stop]
            t0 = time.perf_counter()
            root = simulate(cfg, out, overwrite=force)
        except SvainsError as exc:
            fail(exc)
        typer.echo(f"wrote {root} ({cfg.scenario}, {cfg.duration_s:g} s) in "
                   f"{time.perf_counter() - t0:.1f} s")
