"""Replay of a recorded data set through the online estimator (``svains run``/``compare``).

The only place, with the command line, where data sets meet the estimator: ``replay`` derives
what the recording implies (calibrations, nominal IMU step, feature noise, frame period, a
ground-truth start) into the configuration, merges the streams in time order and feeds them to a
``svains.Navigator`` through its public methods.
"""

from svains.replay.replay import replay, resolve_config, rig_from_dataset

__all__ = ["replay", "resolve_config", "rig_from_dataset"]
