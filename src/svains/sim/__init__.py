"""Simulator: the paper's village flight and real-trajectory flights, written as ASL data sets."""
