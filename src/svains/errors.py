"""Typed exceptions raised by the library (never ``SystemExit``; only ``cli/`` prints)."""


class SvainsError(Exception):
    """Base class of every error the library raises on purpose."""


class DatasetError(SvainsError):
    """A data set on disk is missing, malformed or inconsistent."""


class CalibrationError(DatasetError):
    """A calibration file lacks or has invalid fields."""


class FilterError(SvainsError):
    """The estimator reached an invalid state (e.g. a covariance that is not SPD)."""


class InitialisationError(SvainsError):
    """The estimator could not be initialised from the data given."""


class StartFixesRefusedError(InitialisationError):
    """An in-flight start's first GPS fixes disagree with the IMU: a later pair may serve."""


class ConfigError(SvainsError):
    """A configuration value is invalid."""


class OutputError(SvainsError):
    """An output location cannot be used (it holds a data set to keep, or is not a folder)."""


class AlignmentError(SvainsError):
    """A trajectory alignment is undetermined (e.g. se3 on collinear positions)."""


class ClosedError(SvainsError):
    """A ``Navigator`` was fed after ``close()``: a run's estimator serves that run only."""
