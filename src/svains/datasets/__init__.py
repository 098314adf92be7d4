"""Readers and writers of the ASL/EuRoC layout (extended), KITTI odometry and trajectory files."""
