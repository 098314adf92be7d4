"""Test helper: feed a data set to a ``Navigator`` with extra stand-in vision frames."""

from __future__ import annotations

import heapq
from dataclasses import replace
from typing import Any

import numpy as np

from svains.navigation import navigator_core
from svains.navigation.navigator import Navigator
from svains.replay.replay import feed, measurements, rig_from_dataset
from svains.sensors.types import CameraCalib


class StubFrames:
    """A tracks source that has a frame whenever one is fed (no tracks)."""

    kind = "features"
    rig = None
    pixel_noise_std = 1.0

    def push(self, *args: Any) -> bool:
        return True

    def discard(self, t_ns: int) -> None:
        pass

    def tracks_at(self, t_ns: int, motion_prior: Any = None) -> None:
        return None


class _StubNavigator(Navigator):
    def _make_source(self, kind: str) -> Any:
        return StubFrames()


def _camera(name: str, x_m: float) -> CameraCalib:
    """A 640x480 pinhole camera ``x_m`` along the body's x axis."""
    T_B_C = np.eye(4)
    T_B_C[0, 3] = x_m
    return CameraCalib(name, T_B_C, 5.0, (640, 480), np.array([400.0, 400.0, 320.0, 240.0]),
                       "radtan", np.zeros(4))


def run_with_updater(monkeypatch: Any, ds: Any, config: Any, updater: Any,
                     frame_times: np.ndarray, initial_state: Any = None) -> Any:
    """Replay ``ds`` with ``updater`` called at ``frame_times`` (config.method must be a
    vision method); returns the ``RunResult``."""
    monkeypatch.setattr(navigator_core, "make_vision_updater", lambda *a, **k: updater)
    rig = rig_from_dataset(ds)
    if rig.cam0 is None or rig.cam1 is None:
        # a vision method needs a stereo pair on the rig; the stand-in updater reads none
        rig = replace(rig, cam0=_camera("cam0", 0.0), cam1=_camera("cam1", 0.1))
    nav = _StubNavigator(config, rig, initial_state=initial_state)
    empty = np.zeros((0, 2))
    frames = ((int(t), 3, ("features", np.zeros(0, np.int64), empty, empty))
              for t in frame_times)
    t0 = int(ds.imu.t_ns[0])
    for t, kind, payload in heapq.merge(measurements(ds, config, t0), frames,
                                        key=lambda e: (e[0], e[1])):
        feed(nav, kind, t, payload)
    return nav.close()


def updater_for(method: str, ds: Any, vision: Any) -> Any:
    """A vision updater for ``method`` fed with every recorded frame of ``ds.features`` (pixel
    noise from the stream unless ``vision`` sets it); ``.frame_times`` lists the frames that
    carry tracks."""
    from dataclasses import replace

    from svains.navigation.tracks import TrackOptions, frame_slices
    from svains.navigation.vision import make_vision_updater
    from svains.navigation.vision_sources import FeatureFrames, rig_from_calibrations
    from svains.replay.replay import history_from_dataset

    if vision.pixel_noise_std is None:
        vision = replace(vision, pixel_noise_std=float(ds.features.pixel_noise_std))
    src = FeatureFrames(rig_from_calibrations(ds.cam0, ds.cam1),
                        TrackOptions(max_row_diff_px=vision.max_row_diff_px,
                                     egomotion=method == "lc"))  # fmt: skip
    times, bounds = frame_slices(ds.features)
    with_tracks = []
    for k in range(0, len(times), vision.frame_stride):
        rows = slice(bounds[k], bounds[k + 1])
        fs = ds.features
        if src.push(int(times[k]), fs.track_id[rows], fs.uv_left[rows], fs.uv_right[rows]):
            with_tracks.append(int(times[k]))
    history = None if ds.imu is None else history_from_dataset(ds)
    upd = make_vision_updater(method, vision, src, history, rig_from_dataset(ds))
    upd.frame_times = np.array(with_tracks, np.int64)
    return upd
