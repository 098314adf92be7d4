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
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from svains.filter.ukf import UKF
from svains.models.clones import (
    CloneManifold,
    augment_calibration,
    augment_clone,
    marginalize_clone,
)
from svains.models.manifold import NavManifold
from svains.models.state import DP, DTH

if TYPE_CHECKING:
    from svains.navigation.options import VisionOptions

F64 = NDArray[np.float64]


class CloneWindow:
    """Times (ns) of the clones in ``ukf``'s state, in state order."""

    def __init__(self, extrinsic_std_rad: float | None = None) -> None:
        """``extrinsic_std_rad``: estimate the camera rotation correction with this prior
        standard deviation per axis (None: the calibration is taken as exact)."""
        self.times: list[int] = []
        self.extrinsic_std_rad = extrinsic_std_rad
        # Last estimate of δφ_C (3,) rad and its standard deviations (3,) rad (``after_frame``).
        self.extrinsic: tuple[F64, F64] | None = None

    def calib(self, ukf: UKF) -> slice | None:
        """Columns of ``δφ_C`` in ``ukf.x`` (None: not estimated)."""
        manifold = ukf.manifold
        if not isinstance(manifold, CloneManifold) or manifold.calib is None:
            return None
        return manifold.calib[0]

    def columns(self, ukf: UKF, t_ns: int | None) -> tuple[slice, slice] | None:
        """Columns ``(p_W_B, q_W_B_wxyz)`` of the clone at ``t_ns`` in ``ukf.x`` (None: none)."""
        if t_ns is None or int(t_ns) not in self.times:
            return None
        manifold = ukf.manifold
        assert isinstance(manifold, CloneManifold)
        return manifold.columns(self.times.index(int(t_ns)))

    def after_frame(self, ukf: UKF, t_ns: int, reference_ns: int | None) -> None:
        """Clone the pose at ``t_ns`` when it is the next tracks' reference; drop the others."""
        manifold = ukf.manifold
        if not isinstance(manifold, CloneManifold):
            assert isinstance(manifold, NavManifold)
            manifold = CloneManifold(manifold, 0)
        x, P = ukf.x, ukf.P
        times = list(self.times)
        # The linear map from the old tangent to the new one (rows of zeros: a new,
        # independent state), for a smoother to chain through the resize (``UKF.resize``).
        T = np.eye(manifold.ndx)
        if self.extrinsic_std_rad is not None and manifold.n_calib == 0:
            var = self.extrinsic_std_rad**2 * np.eye(3)
            n_nav = manifold.nav.ndx
            x, P, manifold = augment_calibration(x, P, manifold, np.zeros(3), var)
            T = np.vstack([T[:n_nav], np.zeros((3, T.shape[1])), T[n_nav:]])
        if reference_ns is not None and int(reference_ns) == int(t_ns) and t_ns not in times:
            x, P, manifold = augment_clone(x, P, manifold)
            T = np.vstack([T, T[DP], T[DTH]])  # a copy of the pose's rows
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
            self.extrinsic = (ukf.x[cx].copy(), np.sqrt(np.diag(ukf.P)[cdx]))

    def summary(self) -> dict[str, list[float]]:
        """The estimated rotation correction for ``report.json`` (deg; empty when none)."""
        if self.extrinsic is None:
            return {}
        value, std = self.extrinsic
        return {"extrinsic_rotation_deg": np.degrees(value).tolist(),
                "extrinsic_rotation_std_deg": np.degrees(std).tolist()}


def clone_window(options: VisionOptions) -> CloneWindow | None:
    """The clone window of ``options`` (None unless ``rotation="clone"``), estimating the
    camera rotation when ``estimate_extrinsics`` is set."""
    if options.rotation != "clone":
        return None
    std = np.radians(options.extrinsics_std_deg) if options.estimate_extrinsics else None
    return CloneWindow(std)


def next_reference_ns(source: object, t_ns: int) -> int | None:
    """The frame the next tracks will start from: the image front end's reference frame, or
    ``t_ns`` for recorded tracks (always tracked from the previous frame)."""
    ref = getattr(source, "reference_time_ns", None)
    return int(t_ns) if ref is None else ref()
