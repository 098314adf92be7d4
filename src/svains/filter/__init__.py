"""Sigma-point (unscented) Kalman filter on a manifold; knows nothing of sensors."""
