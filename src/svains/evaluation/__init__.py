"""Trajectory metrics (through evo) and figures."""
