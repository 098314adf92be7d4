"""``replay(dataset, config)``: feed a data set to a ``Navigator``, measurement by measurement.

The streams are merged lazily in time order (ties: GPS, magnetometer, sonar, frame, IMU: a
measurement is fed before the IMU sample stamped with it, so even a zero reordering window
keeps it). Every stream the data set has is fed (GPS also under ``use_gps: false``, for an
``init.mode: gps`` start); the configuration decides what is used. Stereo
pairs are decoded one ahead on a thread (PNG decoding releases the GIL). The run is limited to
``SVAINS_THREADS`` threads per numerical library (``svains.threads``, default 1), entered once.
"""

from __future__ import annotations

import heapq
import logging
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from svains.datasets.loader import PairReader, stereo_pairs
from svains.datasets.stereo_images import check_stereo_images
from svains.datasets.types import DEFAULT_GRAVITY_W, Dataset
from svains.errors import DatasetError
from svains.models.state import BIASED, PAPER
from svains.navigation.imu_history import ImuHistory
from svains.navigation.init import (
    GpsArrays,
    ImuArrays,
    InitData,
    InitialState,
    MagArrays,
    initialise,
)
from svains.navigation.navigator import Navigator
from svains.navigation.options import RunConfig
from svains.navigation.outputs import NavState, RunResult
from svains.navigation.platform_noise import rest_noise
from svains.navigation.tracks import frame_slices
from svains.navigation.vision import tune_for_frames
from svains.navigation.vision_gaps import VISION_GAP_SPACINGS
from svains.sensors.types import Rig
from svains.threads import limit_threads

ProgressFn = Callable[[float], None]
_GPS, _MAG, _SONAR, _FRAME, _IMU = range(5)

log = logging.getLogger(__name__)


def rig_from_dataset(ds: Dataset) -> Rig:
    """The calibrations of ``ds`` and its nominal IMU step (median, seconds)."""
    period = 0.005
    if ds.imu is not None and len(ds.imu.t_ns) > 1:
        t = np.asarray(ds.imu.t_ns, np.int64)
        period = float(np.median(np.diff((t - t[0]) * 1e-9)))
    g = tuple(float(v) for v in (ds.gravity_W if ds.gravity_W is not None else DEFAULT_GRAVITY_W))
    return Rig(g, period, ds.imu_calib, ds.cam0, ds.cam1, ds.gps_calib, ds.mag_calib,  # type: ignore[arg-type]
               ds.sonar_calib)  # fmt: skip


def history_from_dataset(ds: Dataset) -> ImuHistory:
    """The data set's whole IMU stream as an ``ImuHistory`` (body frame, with α)."""
    if ds.imu is None:
        raise DatasetError(f"{ds.name}: no IMU stream")
    history = ImuHistory(None if ds.imu_calib is None else ds.imu_calib.T_B_S[:3, :3])
    for t, g, a in zip(ds.imu.t_ns, ds.imu.gyro_B, ds.imu.accel_B, strict=True):
        history.append(int(t), g, a)
    return history


def resolve_config(ds: Dataset, config: RunConfig) -> RunConfig:
    """``config`` with what the recording implies: the tracks' source (``auto``), the features'
    pixel noise, the ``rotation="imu"`` frame noise (``tune_for_frames``) and the vision gap's
    floor for frames further apart (``faults.vision_max_gap_s``: 2.5 spacings). Idempotent."""
    if config.method == "ins" and config.init.mode != "vision":  # no frames to read
        return config
    v = config.vision
    source = v.source
    if source == "auto":  # without parsing features0 (a lazy stream) when it is absent
        source = "features" if ds.has_stream("features") else "images"
    std = v.pixel_noise_std
    if std is None and source == "features" and ds.features is not None:
        # The recorded features' noise. Images keep None: the front end's 1 px is a
        # placeholder, not a known noise (``VisionOptions.min_disparity``).
        std = float(ds.features.pixel_noise_std)
    config = replace(config, vision=replace(v, source=source, pixel_noise_std=std))
    if source == "features" and ds.features is not None:
        times = ds.features.frame_times()
    elif ds.left is not None:
        times = np.asarray(ds.left.t_ns, np.int64)
    else:
        return config
    times = times[:: max(1, v.frame_stride)]
    period = float(np.median(np.diff(times))) * 1e-9 if len(times) >= 2 else None
    config = tune_for_frames(config, ds.imu_calib, period)
    if period is not None and VISION_GAP_SPACINGS * period > config.faults.vision_max_gap_s:
        # the limit the Core reaches after two frames, from the first: frames 2 s apart
        # warned of a gap before their first frame when it came 2.09 s in (a review)
        gap_s = round(VISION_GAP_SPACINGS * period, 6)
        config = replace(config, faults=replace(config.faults, vision_max_gap_s=gap_s))
    return config


def groundtruth_start(ds: Dataset, config: RunConfig, t_start_ns: int | None) -> InitialState:
    """The initial state from the ground truth (``init.mode: groundtruth``)."""
    imu = ds.imu
    data = InitData(
        ds.name, tuple(ds.gravity_W),  # type: ignore[arg-type]
        None if imu is None else ImuArrays(imu.t_ns, imu.gyro_B, imu.accel_B), ds.imu_calib,
        None if ds.mag is None else MagArrays(ds.mag.t_ns, ds.mag.m_S), ds.mag_calib,
        None if ds.gps is None else GpsArrays(ds.gps.t_ns, ds.gps.p_W_G, ds.gps.v_W_G),
        ds.gps_calib, ds.groundtruth,
    )  # fmt: skip
    layout = BIASED if config.model == "biased" else PAPER
    return initialise(data, layout, config.init, t_start_ns)


def _image_pairs(ds: Dataset, t0: int) -> Iterator[tuple[int, int, Any]]:
    """Stereo pairs from ``t0`` on, each decoded while the previous one is processed."""
    assert ds.left is not None and ds.right is not None
    t, il, ir = stereo_pairs(ds)
    sel = np.flatnonzero(t >= t0)
    if sel.size == 0:
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="svains-png") as pool:

        reader = PairReader(ds)

        def load(k: int) -> Any:
            return pool.submit(reader.read, int(il[k]), int(ir[k]), int(t[k]))

        pending = load(int(sel[0]))
        for n, k in enumerate(sel):
            pair = pending.result()
            if n + 1 < sel.size:
                pending = load(int(sel[n + 1]))
            if pair is not None:  # None: unreadable, dropped (``PairReader`` warned)
                yield int(t[k]), _FRAME, ("images", *pair)


def _feature_frames(ds: Dataset, t0: int) -> Iterator[tuple[int, int, Any]]:
    fs = ds.features
    assert fs is not None
    times, bounds = frame_slices(fs)
    for k in np.flatnonzero(times >= t0):
        rows = slice(bounds[k], bounds[k + 1])
        yield int(times[k]), _FRAME, ("features", fs.track_id[rows], fs.uv_left[rows],
                                      fs.uv_right[rows])  # fmt: skip


def _rows(t_ns: Any, kind: int, t0: int, *arrays: Any) -> Iterator[tuple[int, int, Any]]:
    t = np.asarray(t_ns, np.int64)
    sel = t >= t0
    for t_i, *rows in zip(t[sel].tolist(), *(np.asarray(a)[sel] for a in arrays), strict=True):
        yield t_i, kind, rows


def measurements(
    ds: Dataset, config: RunConfig, t0: int, frames_while: Callable[[], bool] | None = None
) -> Iterator[tuple[int, int, Any]]:
    """``(t_ns, kind, payload)`` of every measurement stamped at or after ``t0``, in order.
    ``frames_while()``: stereo frames for ``ins`` too while it holds (a ``vision`` start's
    odometry), none once it turns false."""
    streams = []
    if ds.gps is not None:
        streams.append(_rows(ds.gps.t_ns, _GPS, t0, ds.gps.p_W_G, ds.gps.v_W_G))
    if ds.mag is not None:
        streams.append(_rows(ds.mag.t_ns, _MAG, t0, ds.mag.m_S))
    if ds.sonar is not None:
        streams.append(_rows(ds.sonar.t_ns, _SONAR, t0, ds.sonar.range_m))
    if config.method != "ins" or frames_while is not None:
        frames = None
        if config.vision.source == "features" and ds.features is not None:
            frames = _feature_frames(ds, t0)
        elif config.vision.source == "images" and ds.left is not None and ds.right is not None:
            frames = _image_pairs(ds, t0)
        if frames is not None:
            streams.append(frames if config.method != "ins" or frames_while is None
                           else _while(frames, frames_while))  # fmt: skip
    assert ds.imu is not None
    streams.append(_rows(ds.imu.t_ns, _IMU, t0, ds.imu.gyro_B, ds.imu.accel_B))
    return heapq.merge(*streams, key=lambda e: (e[0], e[1]))


def _while(events: Iterator[tuple[int, int, Any]],
           keep: Callable[[], bool]) -> Iterator[tuple[int, int, Any]]:  # fmt: skip
    for ev in events:
        if not keep():
            return
        yield ev


def feed(nav: Navigator, kind: int, t: int, payload: Any) -> None:
    """One measurement through the Navigator's public methods."""
    if kind == _IMU:
        nav.feed_imu(t, payload[0], payload[1])
    elif kind == _GPS:
        v = payload[1]  # a NaN row: the receiver gave no velocity with this fix
        nav.feed_gps(t, payload[0], v if np.all(np.isfinite(v)) else None)
    elif kind == _MAG:
        nav.feed_mag(t, payload[0])
    elif kind == _SONAR:
        nav.feed_sonar(t, float(payload[0]))
    elif payload[0] == "images":
        nav.feed_stereo(t, payload[1], payload[2], copy=False)  # freshly decoded, not reused
    else:
        nav.feed_tracks(t, payload[1], payload[2], payload[3])


def replay(
    ds: Dataset, config: RunConfig, progress: ProgressFn | None = None,
    on_output: Callable[[NavState], None] | None = None,
) -> RunResult:
    """Run ``config`` over ``ds`` (``config`` as given: call ``resolve_config`` first to get the
    ``svains run`` behaviour). Returns the Navigator's ``RunResult`` with ``report["dataset"]``.
    """
    if config.method != "ins" and config.vision.source == "images":
        # Swapped left and right streams leave every match on the wrong side: refused before
        # any work (``frontend.stereo_check``; rows that do not fit are warned during the run).
        check_stereo_images(ds)
        n_pairs = stereo_pairs(ds)[0].size if ds.left is not None and ds.right is not None else 0
        if n_pairs < 2:  # vo too: it wrote an empty trajectory with exit 0
            where = "in the bag" if ds.root.is_file() else "with images on disk"
            # a rig with one camera was told of pairs only (a user's probe)
            lacking = [side for side, stream in (("cam0 (left)", ds.left),
                                                 ("cam1 (right)", ds.right))
                       if stream is None or len(stream.t_ns) == 0]  # fmt: skip
            why = (f": no {lacking[0]} images; svains's vision is stereo (without a second "
                   "camera use --method ins)") if len(lacking) == 1 else ""
            raise DatasetError(f"{ds.root}: {n_pairs} stereo pair(s) {where}; image-based "
                               f"vision needs at least 2{why}")  # fmt: skip
    if config.method == "vo":  # stereo only: no IMU needed (KITTI odometry, bare rigs)
        from svains.replay.vo import run as run_vo

        with limit_threads(None):
            return run_vo(ds, config, progress)
    if ds.imu is None or len(ds.imu.t_ns) == 0:
        raise DatasetError(f"{ds.name}: no IMU stream (method {config.method} needs one; "
                           "vo and svains frontend run on stereo alone)")  # fmt: skip
    if ds.imu_calib is None:
        # a bag holds no noise densities: those of another IMU make the filter over- or
        # underconfident (a simulated bag with a camchain alone: ATE 4.8 m against 0.06 m)
        log.warning("%s: no IMU calibration, so EuRoC's ADIS16448 noise densities and an IMU "
                    "at the body origin are assumed: give the IMU's Kalibr imu.yaml "
                    "(--imu-calib) or imu0/sensor.yaml", ds.name)  # fmt: skip
    t_imu = np.asarray(ds.imu.t_ns, np.int64)
    t0 = int(t_imu[0]) + int(config.replay.start_s * 1e9)
    span = int(t_imu[-1]) - t0  # ns of IMU from the start (outages count from there)
    if span <= 0:
        raise DatasetError(f"{ds.name}: the start {config.replay.start_s:g} s (--start, "
                           f"replay.start_s) is past the end of its IMU stream, "
                           f"{(int(t_imu[-1]) - int(t_imu[0])) * 1e-9:.2f} s long")  # fmt: skip
    for start, length in config.gps_outages:
        if start >= span * 1e-9:
            log.warning("the GPS outage %g:%g starts after the end of the data (%.1f s of IMU "
                        "from the start): nothing is cut", start, length, span * 1e-9)  # fmt: skip
    init = None
    if config.init.mode == "groundtruth":
        init = groundtruth_start(ds, config, t0 if config.replay.start_s > 0 else None)

    rig = rig_from_dataset(ds)
    rest = None
    if config.init.mode != "static" and rig.imu is not None and config.noise.static_rule:
        # a recording that begins at rest lends it to a later or moving start
        rest = rest_noise(t_imu, ds.imu.gyro_B, ds.imu.accel_B, config.init, rig.imu.T_B_S[:3, :3])
    nav = Navigator(config, rig, on_output=on_output, initial_state=init,
                    keep_outputs=False, rest_noise=rest)  # the run's result holds the outputs
    next_report = t0
    # Once around the whole loop (entering costs ~0.6 ms); under ``svains`` it keeps the
    # command's ``--threads``.
    with limit_threads(None):
        starting = (lambda: nav.core is None) if config.init.mode == "vision" else None
        for t, kind, payload in measurements(ds, config, t0, starting):
            feed(nav, kind, t, payload)
            if nav.status == "finished":
                break
            if progress is not None and t >= next_report:
                progress(min(1.0, (t - t0) / span))
                next_report = t + span // 200
        result = nav.close()
    if result.tracks is not None and ds.cam0 is not None and ds.cam1 is not None:
        # tracks.csv holds raw left-image pixels (what the viewer draws on the recorded image).
        from svains.frontend.rectify import StereoRectifier

        rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
        result.tracks.make_raw(rect.unrectify_points)
    if progress is not None:
        progress(1.0)
    rep = result.report
    result.report = {"method": rep.pop("method"), "model": rep.pop("model"), "dataset": ds.name,
                     **rep}  # fmt: skip
    return result
