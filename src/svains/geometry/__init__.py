"""Rotations, poses and camera models: pure numpy, no I/O."""
