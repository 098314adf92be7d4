"""The pose clones a vision updater keeps in the filter's state (``rotation="clone"``).

``CloneWindow`` augments the UKF's state with a copy of the body pose at a frame time
(``models.clones``) and marginalises the clones no later frame will be measured against. Keyed
by the frame time the filter was propagated to. One frame's cycle:

1. the updater asks ``columns(ukf, tracks.t_prev_ns)`` for the clone of the tracks' reference
   frame (None: no clone, e.g. the first frame after the start: the frame is skipped);
2. it fuses with the exact relative-motion models of ``models.vision_clone``;
3. ``after_frame(ukf, t_ns, reference_ns)`` (once per frame, fused or not) clones the pose at
   ``t_ns`` if the next tracks will start there, and drops every clone but the reference's.

The front end may hold its reference frame (a frame it could not track keeps the older one):
``reference_ns`` is then older than ``t_ns`` and its clone stays. At most one clone is kept, so
the biased UKF has 49 sigma points instead of 37.

**Online camera-IMU rotation** (``vision.estimate_extrinsics``): the first ``after_frame`` also
adds a calibration block ``δφ_C`` (3, rad, left-camera axes; ``R_B_C = R_B_C,calib Exp(δφ_C)``,
both cameras turn together) with zero mean and ``extrinsic_std_rad`` per axis, constant in the
process model (like OpenVINS' ``calib_cam_extrinsics``, rotation only: a real rig's rotation
error tilts every frame's translation direction, while a lever-arm error of a few mm is
invisible at these step lengths). The exact relative-motion models then see it per sigma point
(``models.vision_clone``) and the clones' correlation with it makes it observable from the IMU
motion between frames. Adds 3 tangent dimensions (55 sigma points with one clone).

**The camera-IMU rotation considered** (``vision.consider_extrinsics_std_deg``): the same
``δφ_C`` block, with zero mean and the given standard deviation per axis, as a consider
parameter (``CloneManifold.n_consider``): the models see it per sigma point as above, so the
state's covariance carries its effect, and the UKF never updates it (``UKF._set_posterior``).

**Online camera-IMU time offset** (``vision.estimate_time_offset``): one more calibration
number after ``δφ_C`` (when both are on), ``t_d`` (s, Kalibr's ``t_imu = t_cam + t_d``), the
residual of the offset the data's calibration already applied to the image stamps
(``CameraCalib.timeshift_cam_imu_s``), with zero mean and ``time_offset_std_ms``. The clone of
a frame is then the body pose at the image's IMU time ``t_k + t_d``
(``augment_shifted_clone_sigma``: moved through the IMU samples over the current estimate, the
offset's spread taken by quadrature over the same samples, ``models.time_offset``, with its
correlation to ``t_d``) and the models move the current pose
alike (``time_offset.shifted_pose``): the relative motion between the two is shifted at both
ends, and ``t_d`` becomes observable wherever the rig's motion changes. Adds 1 tangent
dimension (2 sigma points); constant in the process model.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import UKF
from svains.models.clones import (
    SHIFT_REACH_SIGMA,
    CloneManifold,
    as_clone_manifold,
    augment_calibration,
    augment_clone,
    augment_consider,
    augment_independent_clone,
    augment_shifted_clone_sigma,
    marginalize_clone,
)
from svains.models.state import BA, BG, BIASED, DP, DTH, W
from svains.models.time_offset import ShiftIncrement, ShiftTable, shift_table
from svains.navigation.imu_history import ImuHistory

# The reach of the offset's table (s) either side of its estimate: beyond it a sigma point moves
# to first order from the last node (the IMU past ``buffer.window_s`` is held anyway).
MAX_SHIFT_SPAN_S = 0.25

if TYPE_CHECKING:
    from svains.navigation.options import VisionOptions

F64 = NDArray[np.float64]


class CloneWindow:
    """Times (ns) of the clones in ``ukf``'s state, in state order."""

    def __init__(
        self, extrinsic_std_rad: float | None = None, time_offset_std_s: float | None = None,
        time_offset_applied_s: float = 0.0, history: ImuHistory | None = None,
        g_W: tuple[float, float, float] = (0.0, 0.0, -9.81),
        consider_std_rad: float | None = None,
    ) -> None:
        """``extrinsic_std_rad``: estimate the camera rotation correction with this prior
        standard deviation per axis (None: the calibration is taken as exact, or considered);
        ``consider_std_rad``: carry it instead as a consider parameter of this standard
        deviation per axis, never estimated (the Schmidt filter; ignored while estimated);
        ``time_offset_std_s``: estimate the camera-IMU time offset's residual with this prior
        standard deviation (s; None: the offset is taken as exact); ``time_offset_applied_s``
        the offset the data's calibration already applied to the image stamps (s, reported
        with the estimate); ``history`` the IMU samples that move a pose by the offset
        (``models.time_offset``; None: first order only) and ``g_W`` (3,) m/s² gravity."""
        self.history = history
        self.g_W = np.asarray(g_W, dtype=float)
        self.times: list[int] = []
        self.extrinsic_std_rad = extrinsic_std_rad
        self.time_offset_std_s = time_offset_std_s
        self.time_offset_applied_s = float(time_offset_applied_s)
        # Last estimate of δφ_C (3,) rad and its standard deviations (3,) rad (``after_frame``).
        self.extrinsic: tuple[F64, F64] | None = None
        # (t_ns, residual t_d s, its std s) after every frame while the offset is estimated.
        self.time_offset: list[tuple[int, float, float]] = []
        self.consider_std_rad = None if extrinsic_std_rad is not None else consider_std_rad

    @property
    def n_calib(self) -> int:
        """Calibration numbers this window adds: ``δφ_C`` (3) then ``t_d`` (1), each if on."""
        return 3 * (self.extrinsic_std_rad is not None) + (self.time_offset_std_s is not None)

    def calib(self, ukf: UKF) -> slice | None:
        """Columns of ``δφ_C`` in ``ukf.x`` (None: neither estimated nor considered)."""
        manifold = ukf.manifold
        if (not isinstance(manifold, CloneManifold) or manifold.calib is None
                or (self.extrinsic_std_rad is None and manifold.n_consider == 0)):
            return None
        a = manifold.calib[0].start
        return slice(a, a + 3)

    def td(self, ukf: UKF, t_ns: int) -> tuple[int, ShiftIncrement | ShiftTable] | None:
        """The time offset's column in ``ukf.x`` and the ``ShiftTable`` that moves the pose at
        the frame ``t_ns`` by the offset of each sigma point (None: not estimated): nodes at
        the IMU samples within the sigma points' reach, ``scale · σ`` (at most
        ``MAX_SHIFT_SPAN_S``) either side of the estimate."""
        manifold = ukf.manifold
        if (not isinstance(manifold, CloneManifold) or manifold.calib is None
                or self.time_offset_std_s is None):
            return None
        return self._increment(ukf.x, ukf.P, manifold, t_ns, ukf.points.scale)

    def _increment(
        self, x: F64, P: F64, manifold: CloneManifold, t_ns: int, reach: float
    ) -> tuple[int, ShiftIncrement | ShiftTable]:
        """The offset's column in ``x`` and the IMU's motion from ``t_ns`` over the offset
        ``x[col]`` (s) with the biases of ``x``: the ``shift_table`` at the samples within
        ``reach · σ`` (``P``'s, at most ``MAX_SHIFT_SPAN_S``) either side of it, its entry at
        the estimate alone when σ is 0; first order without an IMU history."""
        assert manifold.calib is not None
        col = manifold.calib[0].stop - 1
        tangent = manifold.calib[1].stop - 1
        span_s = min(reach * float(np.sqrt(max(P[tangent, tangent], 0.0))), MAX_SHIFT_SPAN_S)
        tau = float(x[col])
        nav_nx = manifold.nav.nx
        bg, ba = (x[BG], x[BA]) if nav_nx == BIASED.nx else (np.zeros(3), np.zeros(3))
        h = self.history
        if h is None or h.n < 2:
            return col, ShiftIncrement.first_order(x[W], self.g_W)
        t = h.t_ns
        # Only the samples around [t, t + τ ± span] (plus one either side for the interpolation).
        a_ns = int(t_ns) + min(round((tau - span_s) * 1e9), 0)
        b_ns = int(t_ns) + max(round((tau + span_s) * 1e9), 0)
        lo = int(np.searchsorted(t, a_ns, "left")) - 1
        hi = int(np.searchsorted(t, b_ns, "right")) + 1
        lo, hi = max(lo, 0), min(max(hi, lo + 2), h.n)
        table = shift_table(t[lo:hi], h.gyro_B[lo:hi], h.accel_B[lo:hi], int(t_ns), tau, span_s,
                            bg, ba, self.g_W)  # fmt: skip
        return col, (table if span_s > 0.0 else table.center)

    def columns(self, ukf: UKF, t_ns: int | None) -> tuple[slice, slice] | None:
        """Columns ``(p_W_B, q_W_B_wxyz)`` of the clone at ``t_ns`` in ``ukf.x`` (None: none)."""
        if t_ns is None or int(t_ns) not in self.times:
            return None
        manifold = ukf.manifold
        assert isinstance(manifold, CloneManifold)
        return manifold.columns(self.times.index(int(t_ns)))

    def _with_calibration(
        self, x: F64, P: F64, manifold: CloneManifold
    ) -> tuple[F64, F64, CloneManifold]:
        """The state with this window's calibration block added (zero mean, prior stds)."""
        var = []
        if self.extrinsic_std_rad is not None:
            var += [self.extrinsic_std_rad**2] * 3
        if self.time_offset_std_s is not None:
            var.append(self.time_offset_std_s**2)
        return augment_calibration(x, P, manifold, np.zeros(len(var)), np.diag(var))

    def after_frame(self, ukf: UKF, t_ns: int, reference_ns: int | None) -> None:
        """Clone the pose at ``t_ns`` when it is the next tracks' reference; drop the others."""
        manifold = as_clone_manifold(ukf.manifold)
        x, P = ukf.x, ukf.P
        times = list(self.times)
        # The linear map from the old tangent to the new one (rows of zeros: a new,
        # independent state), for a smoother to chain through the resize (``UKF.resize``).
        T = np.eye(manifold.ndx)
        if self.n_calib and manifold.n_calib == 0:
            n_nav = manifold.nav.ndx
            x, P, manifold = self._with_calibration(x, P, manifold)
            T = np.vstack([T[:n_nav], np.zeros((self.n_calib, T.shape[1])), T[n_nav:]])
        if self.consider_std_rad is not None and manifold.n_consider == 0:
            # in front of any estimated calibration numbers (``augment_consider``)
            n_nav = manifold.nav.ndx
            x, P, manifold = augment_consider(x, P, manifold,
                                              np.eye(3) * self.consider_std_rad**2)  # fmt: skip
            T = np.vstack([T[:n_nav], np.zeros((3, T.shape[1])), T[n_nav:]])
        if reference_ns is not None and int(reference_ns) == int(t_ns) and t_ns not in times:
            if self.time_offset_std_s is None:
                x, P, manifold = augment_clone(x, P, manifold)
                T = np.vstack([T, T[DP], T[DTH]])  # a copy of the pose's rows
            else:
                # The pose at the image's IMU time, t_k + t_d: not a copy of the pose's rows
                # but moved by the offset, through quadrature over its spread as the vision
                # models move the current pose (``models.clones.augment_shifted_clone_sigma``).
                col, inc = self._increment(x, P, manifold, t_ns, SHIFT_REACH_SIGMA)
                x, P, manifold, S = augment_shifted_clone_sigma(x, P, manifold, col, inc)
                T = np.vstack([T, S @ T])
            times.append(int(t_ns))
        for i in reversed(range(len(times))):
            if reference_ns is None or times[i] != int(reference_ns):
                T = np.delete(T, np.arange(manifold.ndx)[manifold.tangent(i)], axis=0)
                x, P, manifold = marginalize_clone(x, P, manifold, i)
                del times[i]
        if times != self.times or manifold is not ukf.manifold:
            ukf.resize(manifold, x, np.asarray(P), T)
        self.times = times
        if manifold.calib is not None:
            cx, cdx = manifold.calib
            value, std = ukf.x[cx].copy(), np.sqrt(np.diag(ukf.P)[cdx])
            if self.extrinsic_std_rad is not None:
                self.extrinsic = (value[:3], std[:3])
            if self.time_offset_std_s is not None:
                self.time_offset.append((int(t_ns), float(value[-1]), float(std[-1])))

    def add_keyframe(self, ukf: UKF, t_ns: int, p_W_B: F64, q_W_B_wxyz: F64,
                     P_pose: F64) -> None:  # fmt: skip
        """Put a stored keyframe's pose at ``t_ns`` (ns; ``p_W_B`` (3,) m, ``q_W_B_wxyz`` (4,),
        covariance ``P_pose`` (6, 6)) in the state as a clone uncorrelated with it, for one
        frame's relocalisation (``navigation.relocalise``); the next ``after_frame`` drops it
        as any clone that is not the next reference."""
        if int(t_ns) in self.times:
            raise ValueError(f"the state already holds a clone at t={t_ns} ns")
        manifold = as_clone_manifold(ukf.manifold)
        x, P, manifold = augment_independent_clone(ukf.x, ukf.P, manifold, p_W_B, q_W_B_wxyz,
                                                   P_pose)  # fmt: skip
        # The new rows are a state of its own (zeros in the map from the old tangent).
        T = np.vstack([np.eye(ukf.P.shape[0]), np.zeros((P.shape[0] - ukf.P.shape[0],
                                                         ukf.P.shape[0]))])  # fmt: skip
        ukf.resize(manifold, x, P, T)
        self.times = [*self.times, int(t_ns)]

    def drop(self, ukf: UKF, t_ns: int) -> None:
        """Marginalise the clone at ``t_ns`` (ns) out of the state."""
        i = self.times.index(int(t_ns))
        manifold = as_clone_manifold(ukf.manifold)
        T = np.delete(np.eye(manifold.ndx), np.arange(manifold.ndx)[manifold.tangent(i)], axis=0)
        x, P, manifold = marginalize_clone(ukf.x, ukf.P, manifold, i)
        ukf.resize(manifold, x, np.asarray(P), T)
        self.times = [t for j, t in enumerate(self.times) if j != i]

    def summary(self) -> dict[str, Any]:
        """The estimated calibration for ``report.json`` (empty when none): the rotation
        correction (deg) and the time offset (ms, total: the applied one plus the residual,
        Kalibr's ``timeshift_cam_imu``), with their standard deviations, and the offset's
        history (``time_offset_history``: ``t_s``, ``value_ms``, ``std_ms``, at most one entry
        per ``HISTORY_PERIOD_S`` plus the last)."""
        out: dict[str, Any] = {}
        if self.extrinsic is not None:
            value, std = self.extrinsic
            out.update(extrinsic_rotation_deg=np.degrees(value).tolist(),
                       extrinsic_rotation_std_deg=np.degrees(std).tolist())  # fmt: skip
        if self.consider_std_rad is not None:
            out.update(
                extrinsic_rotation_considered_std_deg=float(np.degrees(self.consider_std_rad)))
        if self.time_offset:
            t, v, s = (np.asarray(c) for c in zip(*self.time_offset, strict=True))
            v = (v + self.time_offset_applied_s) * 1e3
            keep = _thinned(t, HISTORY_PERIOD_S)
            out.update(
                time_offset_ms=float(v[-1]), time_offset_std_ms=float(s[-1] * 1e3),
                time_offset_applied_ms=self.time_offset_applied_s * 1e3,
                time_offset_history={"t_s": (t[keep] * 1e-9).tolist(),
                                     "value_ms": v[keep].tolist(),
                                     "std_ms": (s[keep] * 1e3).tolist()},
            )  # fmt: skip
        return out


# ``report.json``'s time-offset history: at most one entry per this period (s), so an hour of
# 20 Hz frames stays a few hundred kB; enough for the plot and for the campaign's checks.
HISTORY_PERIOD_S = 0.2


def _thinned(t_ns: NDArray[np.int64], period_s: float) -> NDArray[np.int64]:
    """Indices of ``t_ns`` (N,) at least ``period_s`` apart, the last always kept."""
    keep, last = [], None
    for i, t in enumerate(t_ns.tolist()):
        if last is None or t - last >= period_s * 1e9:
            keep.append(i)
            last = t
    if keep[-1] != len(t_ns) - 1:
        keep.append(len(t_ns) - 1)
    return np.asarray(keep, np.int64)


def clone_window(
    options: VisionOptions, time_offset_applied_s: float = 0.0,
    history: ImuHistory | None = None, g_W: tuple[float, float, float] = (0.0, 0.0, -9.81),
) -> CloneWindow | None:
    """The clone window of ``options`` (None unless ``rotation="clone"``), estimating the
    camera rotation when ``estimate_extrinsics`` is set and the camera-IMU time offset when
    ``estimate_time_offset`` is (its applied part ``time_offset_applied_s``, s, reported; the
    IMU ``history`` and gravity ``g_W`` move the poses by it)."""
    if options.rotation != "clone":
        return None
    std = np.radians(options.extrinsics_std_deg) if options.estimate_extrinsics else None
    td_std = options.time_offset_std_ms * 1e-3 if options.estimate_time_offset else None
    con = options.consider_extrinsics_std_deg
    return CloneWindow(std, td_std, time_offset_applied_s, history, g_W,
                       None if con is None else float(np.radians(con)))


def next_reference_ns(source: object, t_ns: int) -> int | None:
    """The frame the next tracks will start from: the image front end's reference frame, or
    ``t_ns`` for recorded tracks (always tracked from the previous frame)."""
    ref = getattr(source, "reference_time_ns", None)
    return int(t_ns) if ref is None else ref()
