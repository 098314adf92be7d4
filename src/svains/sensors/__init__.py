"""Sensor calibrations, the rig and measurement types (no I/O, no data sets)."""
