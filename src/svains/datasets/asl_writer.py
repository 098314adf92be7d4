"""Write a data set in the ASL/EuRoC layout, extended (``docs/formats.md``).

The simulator writes through :class:`AslWriter`; :func:`svains.datasets.load_dataset` reads it
back bit-exactly (floats are written with their shortest exact text).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from svains.datasets._image_io import write_grey
from svains.datasets._textio import write_csv, write_sensor_yaml
from svains.datasets.types import (
    CameraCalib,
    FeatureStream,
    GpsCalib,
    GpsStream,
    GroundTruth,
    ImuCalib,
    ImuStream,
    MagCalib,
    MagStream,
    SonarCalib,
    SonarStream,
)
from svains.errors import DatasetError

IMU_HEADER = (
    "timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
GT_HEADER = (
    "timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
    "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
    "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
    "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)
CAM_HEADER = "timestamp [ns],filename"
GPS_HEADER = (
    "timestamp [ns],p_WG_x [m],p_WG_y [m],p_WG_z [m],v_WG_x [m s^-1],v_WG_y [m s^-1],"
    "v_WG_z [m s^-1]"
)
GPS_POSITION_HEADER = "timestamp [ns],p_WG_x [m],p_WG_y [m],p_WG_z [m]"
MAG_HEADER = "timestamp [ns],m_B_x [G],m_B_y [G],m_B_z [G]"
SONAR_HEADER = "timestamp [ns],range [m]"
FEATURES_HEADER = "timestamp [ns],track_id,u_left [px],v_left [px],u_right [px],v_right [px]"


def _rate_hz(t_ns: NDArray[np.int64]) -> float:
    """Nominal rate from the median sample spacing (0 when fewer than two samples)."""
    t = np.unique(np.asarray(t_ns, dtype=np.int64))
    if t.size < 2:
        return 0.0
    return float(1e9 / np.median(np.diff(t)))


class AslWriter:
    """Creates ``root/mav0/<stream>/{data.csv, sensor.yaml}`` for each stream written.

    Every method writes one stream completely; streams may be written in any order.
    """

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        self.mav0 = self.root / "mav0"
        self.mav0.mkdir(parents=True, exist_ok=True)

    def _folder(self, name: str) -> Path:
        d = self.mav0 / name
        d.mkdir(parents=True, exist_ok=True)
        return d

    def write_body(self, gravity_W: ArrayLike, comment: str = "svains data set") -> Path:
        """``body.yaml`` with ``gravity_W`` (3,) m/s²."""
        g = np.asarray(gravity_W, dtype=float).reshape(3)
        path = self.mav0 / "body.yaml"
        write_sensor_yaml(path, [("gravity_W", g)], comment=comment)
        return path

    def write_imu(self, stream: ImuStream, calib: ImuCalib, name: str = "imu0") -> Path:
        """``imu0``: gyro (rad/s) and specific force (m/s²) in the sensor frame, noise densities."""
        d = self._folder(name)
        write_csv(d / "data.csv", IMU_HEADER, [stream.t_ns, stream.gyro_B, stream.accel_B])
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "imu"),
                ("T_BS", calib.T_B_S),
                ("rate_hz", calib.rate_hz),
                ("gyroscope_noise_density", calib.gyro_noise_density),
                ("gyroscope_random_walk", calib.gyro_random_walk),
                ("accelerometer_noise_density", calib.accel_noise_density),
                ("accelerometer_random_walk", calib.accel_random_walk),
                *([("gyroscope_range", calib.gyro_range)] if calib.gyro_range else []),
                *([("accelerometer_range", calib.accel_range)] if calib.accel_range else []),
            ],
            comment="svains IMU",
        )
        return d

    def write_camera(
        self, calib: CameraCalib, t_ns: ArrayLike, images: Iterable[NDArray[np.uint8]]
    ) -> Path:
        """``<calib.name>/``: one PNG per timestamp (written as ``images`` yields them), the
        ``data.csv`` index and the Kalibr ``sensor.yaml``. ``images`` must yield ``len(t_ns)``
        uint8 (H, W) arrays."""
        t = np.asarray(t_ns, dtype=np.int64)
        d = self._folder(calib.name)
        data = d / "data"
        data.mkdir(exist_ok=True)
        names = [f"{int(ti)}.png" for ti in t]
        n = 0
        for n, img in enumerate(images, start=1):
            if n > len(names):
                raise ValueError(f"{calib.name}: more images than the {len(names)} timestamps")
            write_grey(data / names[n - 1], img)
        if n != len(names):
            raise ValueError(f"{calib.name}: {n} images for {len(names)} timestamps")
        write_csv(d / "data.csv", CAM_HEADER, [t, np.asarray(names, dtype=object)])
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "camera"),
                ("T_BS", calib.T_B_C),
                ("rate_hz", calib.rate_hz),
                ("resolution", list(calib.resolution)),
                ("camera_model", "pinhole"),
                ("intrinsics", calib.intrinsics),
                ("distortion_model", calib.distortion_model),
                ("distortion_coefficients", calib.distortion),
            ],
            comment=f"svains {calib.name}",
        )
        return d

    def write_groundtruth(self, gt: GroundTruth, name: str = "state_groundtruth_estimate0") -> Path:
        """EuRoC 16-column ground truth of the body frame (position, q wxyz, velocity, biases)."""
        d = self._folder(name)
        write_csv(
            d / "data.csv",
            GT_HEADER,
            [gt.t_ns, gt.p_W_B, gt.q_W_B_wxyz, gt.v_W_B, gt.bg_B, gt.ba_B],
        )
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "visual-inertial"),
                ("T_BS", np.eye(4)),
                ("rate_hz", _rate_hz(gt.t_ns)),
            ],
            comment="svains ground truth of the body (IMU) frame",
        )
        return d

    def write_gps(self, stream: GpsStream, calib: GpsCalib, name: str = "gps0") -> Path:
        """``gps0``: antenna position/velocity in W (position only, 4 fields, when no fix has a
        velocity); ``T_BS`` translation = lever arm ``p_B_G``."""
        has_v = stream.has_velocity
        if has_v.any() and not has_v.all():
            raise DatasetError(f"{name}: {int((~has_v).sum())} of {has_v.size} fixes have "
                               "no velocity; gps0 holds velocities for every fix or for none")
        d = self._folder(name)
        shift_ns = np.int64(round(calib.timeshift_gps_imu_s * 1e9))
        # back on the receiver's clock: reading the folder applies the shift again
        t_gps = np.asarray(stream.t_ns, dtype=np.int64) - shift_ns
        if has_v.all():
            write_csv(d / "data.csv", GPS_HEADER, [t_gps, stream.p_W_G, stream.v_W_G])
        else:
            write_csv(d / "data.csv", GPS_POSITION_HEADER, [t_gps, stream.p_W_G])
        T = np.eye(4)
        T[:3, 3] = np.asarray(calib.p_B_G, dtype=float)
        shift: list[tuple[str, Any]] = (
            [("timeshift_gps_imu", calib.timeshift_gps_imu_s)] if shift_ns else []
        )
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "gps"),
                ("T_BS", T),
                ("rate_hz", calib.rate_hz),
                ("position_noise_std", calib.position_noise_std),
                ("velocity_noise_std", calib.velocity_noise_std),
                *shift,
                *([("position_correlation_s", calib.position_correlation_s)]
                  if calib.position_correlation_s > 0 else []),
            ],
            comment="svains GPS (local world frame)",
        )
        return d

    def write_mag(self, stream: MagStream, calib: MagCalib, name: str = "mag0") -> Path:
        """``mag0``: field in the sensor frame (Gauss), reference field ``reference_field_W``."""
        d = self._folder(name)
        write_csv(d / "data.csv", MAG_HEADER, [stream.t_ns, stream.m_S])
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "magnetometer"),
                ("T_BS", calib.T_B_S),
                ("rate_hz", calib.rate_hz),
                ("reference_field_W", calib.m_W),
                ("noise_std", calib.noise_std),
            ],
            comment="svains magnetometer",
        )
        return d

    def write_sonar(self, stream: SonarStream, calib: SonarCalib, name: str = "sonar0") -> Path:
        """``sonar0``: ranges (m) along the sensor's +z axis to flat ground."""
        d = self._folder(name)
        write_csv(d / "data.csv", SONAR_HEADER, [stream.t_ns, stream.range_m])
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "sonar"),
                ("T_BS", calib.T_B_S),
                ("rate_hz", calib.rate_hz),
                ("noise_std", calib.noise_std),
                ("ground_height", calib.ground_height),
            ],
            comment="svains sonar altimeter",
        )
        return d

    def write_features(
        self,
        stream: FeatureStream,
        cameras: Sequence[str] = ("cam0", "cam1"),
        name: str = "features0",
    ) -> Path:
        """``features0``: one row per (frame, track) with left/right rectified pixels."""
        d = self._folder(name)
        write_csv(
            d / "data.csv",
            FEATURES_HEADER,
            [
                stream.t_ns,
                np.asarray(stream.track_id, dtype=np.int64),
                stream.uv_left,
                stream.uv_right,
            ],
        )
        write_sensor_yaml(
            d / "sensor.yaml",
            [
                ("sensor_type", "stereo-features"),
                ("T_BS", np.eye(4)),
                ("rate_hz", _rate_hz(stream.t_ns)),
                ("pixel_noise_std", stream.pixel_noise_std),
                ("cameras", list(cameras)),
            ],
            comment="svains stereo feature tracks",
        )
        return d

    def write_csv_extra(
        self,
        folder: str,
        name: str,
        header: str | Sequence[str],
        array: NDArray[np.generic] | Sequence[NDArray[np.generic]],
    ) -> Path:
        """Any extra ``#``-headed CSV in ``mav0/<folder>/<name>`` (e.g. simulator kinematics).

        ``array`` is one (N, K) array or a sequence of column blocks (e.g. an int64 timestamp
        column then a float (N, K) block), each written by its dtype (ints exact, floats repr).
        """
        d = self._folder(folder)
        blocks = [array] if isinstance(array, np.ndarray) else list(array)
        path = d / name
        write_csv(path, header, blocks)
        return path

    def write_text_extra(self, folder: str, name: str, text: str) -> Path:
        """A free-form text file (e.g. ``scenario.yaml``) in ``mav0/<folder>/<name>``."""
        path = self._folder(folder) / name
        path.write_text(text)
        return path
