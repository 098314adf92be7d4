"""The calibration checks a vision updater runs on each frame's egomotion, as one object: the
camera mount, stamps and focal length against the gyro (``rotation_check``) and the stereo
baseline and accelerometer axes against the accelerometer and the GPS (``scale_check``)."""

from __future__ import annotations

from typing import Any

from svains.frontend.types import StereoTracks
from svains.geometry.camera import RectifiedStereo
from svains.navigation.base import FrameContext
from svains.navigation.imu_history import ImuHistory
from svains.navigation.rotation_check import RotationCheck, rotation_check
from svains.navigation.scale_check import ScaleCheck, scale_check
from svains.sensors.types import Rig


class VisionChecks:
    """Both checks over one IMU history; each only reads and warns."""

    def __init__(self, rotation: RotationCheck, scale: ScaleCheck) -> None:
        self.rotation = rotation
        self.scale = scale

    def observe_frame(self, tr: StereoTracks | None, ctx: FrameContext) -> None:
        """The frame ``tr`` with the filter's state at ``ctx`` (before its update)."""
        self.rotation.observe_frame(tr, ctx)
        self.scale.observe_frame(tr, ctx)

    def summary(self) -> dict[str, Any]:
        """``rotation_check`` and ``scale_check`` for the report's ``vision`` section."""
        return {"rotation_check": self.rotation.summary(), "scale_check": self.scale.summary()}


def vision_checks(history: ImuHistory | None, stereo: RectifiedStereo,
                  rig: Rig) -> VisionChecks | None:  # fmt: skip
    """The checks of ``stereo`` on ``history`` (noise from ``rig.imu``), or None without an
    IMU."""
    rotation = rotation_check(history, stereo.R_B_C, rig.imu)
    scale = scale_check(history, stereo, rig.gravity_W, rig.imu)
    if rotation is None or scale is None:
        return None
    return VisionChecks(rotation, scale)
