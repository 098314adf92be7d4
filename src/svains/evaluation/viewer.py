"""A run as a rerun recording (``.rrd``), or live in the rerun viewer: ``svains view``.

Needs the optional extra ``svains[viz]`` (``rerun-sdk``). Built from what the run folder holds
(``evaluation/run_record.py``) and the data set, on the timeline ``time`` (s from the first
logged state). Entities:

- ``world/groundtruth`` (static line) and ``world/estimate`` (aligned path so far, line), the
  body pose ``world/body`` and its ±3σ position ellipsoid ``world/body_3sigma``;
- ``errors/position_m`` and ``nees`` (scalars), with ground truth;
- ``camera/left`` (the left images inside the run), with ``camera/left/inliers`` and
  ``camera/left/outliers`` (points) and ``camera/left/tracks`` (the last frames of each inlier
  track) when the run wrote ``tracks.csv``;
- ``nis/<sensor>`` (scalars) when the run wrote ``updates.csv``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from svains.datasets.types import Dataset
from svains.errors import ConfigError
from svains.evaluation.run_record import RunErrors, RunRecord, read_run, run_errors

TRACK_TAIL_FRAMES = 5  # frames of each inlier track drawn behind its current point


def _rerun() -> Any:
    try:
        import rerun as rr
    except ImportError:
        raise ConfigError("the viewer needs rerun: pip install 'svains[viz]'") from None
    return rr


def _log_states(rec: Any, rr: Any, run: RunRecord, err: RunErrors | None, t0: int) -> None:
    if err is not None:
        rec.log("world/groundtruth", rr.LineStrips3D([err.p_ref], colors=[(40, 160, 40)]),
                static=True)  # fmt: skip
        t_ns, x, std = err.t_ns, err.x, err.std
    else:
        t_ns, x, std = run.t_ns, run.x, run.std[:, :9]
    for k in range(len(t_ns)):
        rec.set_time("time", duration=(int(t_ns[k]) - t0) * 1e-9)
        q = x[k, 6:10]
        rec.log("world/body", rr.Transform3D(translation=x[k, 0:3],
                                             quaternion=[q[1], q[2], q[3], q[0]]))  # fmt: skip
        rec.log("world/estimate", rr.LineStrips3D([x[: k + 1, 0:3]], colors=[(220, 60, 40)]))
        if np.isfinite(std[k, 0:3]).all():
            ell = rr.Ellipsoids3D(centers=[x[k, 0:3]], half_sizes=[3.0 * std[k, 0:3]])
            rec.log("world/body_3sigma", ell)
        if err is not None:
            rec.log("errors/position_m", rr.Scalars(float(np.linalg.norm(err.e[k, 0:3]))))
            if np.isfinite(err.nees[k]):
                rec.log("nees", rr.Scalars(float(err.nees[k])))


def _log_updates(rec: Any, rr: Any, run: RunRecord, t0: int) -> None:
    u = run.updates
    if u is None:
        return
    for t, s, nis in zip(u["t_ns"].tolist(), u["sensor"].tolist(), u["nis"].tolist(),
                         strict=True):  # fmt: skip
        rec.set_time("time", duration=(int(t) - t0) * 1e-9)
        rec.log(f"nis/{s}", rr.Scalars(float(nis)))


def _log_images(rec: Any, rr: Any, run: RunRecord, ds: Dataset, t0: int, stride: int) -> None:
    left = ds.left
    if left is None or run.t_ns.size == 0:
        return
    sel = np.flatnonzero((left.t_ns >= run.t_ns[0]) & (left.t_ns <= run.t_ns[-1]))[::stride]
    trk = run.tracks
    for i in sel.tolist():
        t = int(left.t_ns[i])
        rec.set_time("time", duration=(t - t0) * 1e-9)
        path = left.paths[i]
        image = rr.EncodedImage(path=path) if path.is_file() else rr.Image(left.load(i))
        rec.log("camera/left", image)
        if trk is None:
            continue
        now = trk["t_ns"] == t
        ok = now & (trk["inlier"] > 0.5)
        uv = np.stack([trk["u_px"], trk["v_px"]], axis=1)
        rec.log("camera/left/inliers", rr.Points2D(uv[ok], colors=[(40, 200, 40)], radii=2.0))
        rec.log("camera/left/outliers", rr.Points2D(uv[now & ~ok], colors=[(230, 40, 40)],
                                                    radii=2.0))  # fmt: skip
        frames = np.unique(trk["t_ns"][trk["t_ns"] <= t])[-TRACK_TAIL_FRAMES:]
        tails = []
        for tid in trk["track_id"][ok].tolist():
            m = (trk["track_id"] == tid) & np.isin(trk["t_ns"], frames)
            if m.sum() > 1:
                tails.append(uv[m][np.argsort(trk["t_ns"][m])])
        rec.log("camera/left/tracks", rr.LineStrips2D(tails, colors=[(40, 200, 40)]))


def write_recording(
    run_dir: Path | str,
    dataset: Dataset | None,
    rrd_path: Path | str | None,
    spawn: bool = False,
    image_stride: int = 1,
) -> Path | None:
    """Log a run (and its data set's ground truth and left images, every ``image_stride``-th)
    to ``rrd_path`` and/or a spawned viewer (``spawn``); returns ``rrd_path``."""
    if rrd_path is None and not spawn:
        raise ConfigError("nowhere to send the recording: give an .rrd path or spawn the viewer")
    if image_stride < 1:
        raise ConfigError(f"image stride must be >= 1, got {image_stride}")
    rr = _rerun()
    run = read_run(run_dir)
    err = None
    if dataset is not None and dataset.groundtruth is not None:
        g = np.asarray(dataset.gravity_W, float)
        err = run_errors(run, dataset.groundtruth, -g / np.linalg.norm(g))
    rec = rr.RecordingStream("svains", recording_id=str(Path(run_dir).resolve()))
    sinks = []
    if rrd_path is not None:
        Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(rrd_path)))
    if spawn:
        rr.spawn(connect=False)
        sinks.append(rr.GrpcSink())
    rec.set_sinks(*sinks)
    t0 = int(run.t_ns[0]) if run.t_ns.size else 0
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    _log_states(rec, rr, run, err, t0)
    _log_updates(rec, rr, run, t0)
    if dataset is not None:
        _log_images(rec, rr, run, dataset, t0, image_stride)
    rec.flush()
    rec.disconnect()
    return Path(rrd_path) if rrd_path is not None else None
