"""Readers and writers of the ASL/EuRoC layout (extended), KITTI odometry and trajectory files."""

from svains.datasets.asl_writer import AslWriter
from svains.datasets.loader import (
    STREAM_ORDER,
    iter_events,
    load_dataset,
    stereo_pairs,
    stream_times,
)

__all__ = [
    "STREAM_ORDER",
    "AslWriter",
    "iter_events",
    "load_dataset",
    "stereo_pairs",
    "stream_times",
]
