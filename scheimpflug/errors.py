"""Typed errors of the toolkit.

Every error a user can cause (a bad rig file, a corrupt frame, a degenerate
calibration set) is one of these, carries the reason in its message, and is
printed by the command line on one line with a non-zero exit status.
"""

__all__ = [
    "CalibrationError",
    "DatasetError",
    "FrameError",
    "LockError",
    "MeshError",
    "RenderError",
    "RigError",
    "ScheimpflugError",
]


class ScheimpflugError(Exception):
    """Base class: an error whose message is fit to show a user as is."""


class RigError(ScheimpflugError, ValueError):
    """An impossible, inconsistent or malformed rig description."""


class DatasetError(ScheimpflugError, ValueError):
    """A malformed dataset spec, or a dataset folder that is missing, foreign or inconsistent."""


class FrameError(ScheimpflugError, ValueError):
    """A missing, unreadable, wrong-size, blank or saturated frame or frame folder."""


class CalibrationError(ScheimpflugError, ValueError):
    """A calibration set that cannot determine the calibration (too few frames, degenerate)."""


class LockError(ScheimpflugError, RuntimeError):
    """A folder is being written by another process (its lock file names the owner)."""


class MeshError(ScheimpflugError, ValueError):
    """An empty, corrupt or non-mesh file, or an unknown part."""


class RenderError(ScheimpflugError, RuntimeError):
    """The renderer cannot run (no usable Mitsuba variant, unwritable output, ...)."""
