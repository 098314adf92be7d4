"""The calibration checks a vision updater runs on each frame's egomotion, as one object: the
camera mount, stamps and focal length against the gyro (``rotation_check``) and the stereo
baseline and accelerometer axes against the accelerometer and the GPS (``scale_check``)."""

from __future__ import annotations

import dataclasses
from typing import Any

from svains.frontend.types import StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.navigation.base import FrameContext
from svains.navigation.imu_history import ImuHistory
from svains.navigation.rotation_check import RotationCheck, rotation_check
from svains.navigation.scale_check import ScaleCheck, scale_check
from svains.navigation.vision_egomotion import tracks_egomotion
from svains.sensors.types import Rig

# Recorded features reach ``tc``/``3d`` with no egomotion: the checks then judged nothing and a
# rig turned 90° on the body ran 804 m off with exit 0, a camchain in millimetres 23 km (a
# user's probe; ``lc``, which estimates one, warned). The front end's estimator gives one for
# the checks over this many frames (2-5 ms each), enough for their verdicts.
CHECK_EGOMOTION_FRAMES = 300


class VisionChecks:
    """Both checks over one IMU history; each only reads and warns."""

    def __init__(self, rotation: RotationCheck, scale: ScaleCheck,
                 stereo: RectifiedStereo | None = None) -> None:  # fmt: skip
        """``stereo``: the rectified rig, to estimate an egomotion for tracks that carry none
        (None: such frames are not judged)."""
        self.rotation = rotation
        self.scale = scale
        self.stereo = stereo
        self.egomotions_estimated = 0
        # set by the caller once the filter was lost (``fault_handling``): the scale check's
        # pairs rest on its attitude and biases, and a lost filter's made a right baseline
        # read 0.669 ± 0.043 (EuRoC every 15th frame, --rotation imu: a user's probe)
        self.filter_lost = False

    def observe_frame(self, tr: StereoTracks | None, ctx: FrameContext) -> None:
        """The frame ``tr`` with the filter's state at ``ctx`` (before its update); tracks
        without an egomotion get the front end's for the first ``CHECK_EGOMOTION_FRAMES``."""
        if (tr is not None and tr.egomotion is None and self.stereo is not None
                and self.egomotions_estimated < CHECK_EGOMOTION_FRAMES):  # fmt: skip
            self.egomotions_estimated += 1
            ego = tracks_egomotion(tr, self.stereo, seed=self.egomotions_estimated)
            if ego is not None:
                tr = dataclasses.replace(tr, egomotion=ego)
        self.rotation.observe_frame(tr, ctx)
        # A mount told wrong (the turns' axes), a gyro's unit or a lens model: the scale
        # check's velocity changes, seen through them, would add a second, wrong cause (a
        # reversed axis, the baseline: a user's probe), so it stands down.
        r = self.rotation
        self.scale.stand_down = (r.warned or r.warned_ratio or r.warned_lens or r.warned_scale
                                 or self.filter_lost)  # fmt: skip
        self.scale.observe_frame(tr, ctx)

    def summary(self) -> dict[str, Any]:
        """``rotation_check`` and ``scale_check`` for the report's ``vision`` section."""
        return {"rotation_check": self.rotation.summary(), "scale_check": self.scale.summary()}


def applied_offset_s(rig: Rig) -> float:
    """The camera-IMU time offset (s) the data's calibration applied to the image stamps."""
    return 0.0 if rig.cam0 is None else float(rig.cam0.timeshift_cam_imu_s)


def vision_checks(history: ImuHistory | None, stereo: RectifiedStereo,
                  rig: Rig) -> VisionChecks | None:  # fmt: skip
    """The checks of ``stereo`` on ``history`` (noise from ``rig.imu``), or None without an
    IMU."""
    rotation = rotation_check(history, stereo.R_B_C, rig.imu, applied_offset_s(rig))
    scale = scale_check(history, stereo, rig.gravity_W, rig.imu)
    if rotation is None or scale is None:
        return None
    return VisionChecks(rotation, scale, stereo)
