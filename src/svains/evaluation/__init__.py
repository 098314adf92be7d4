"""Trajectory metrics (figures equal to evo's, checked in the tests) and figures."""
