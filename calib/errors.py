"""Errors of the radiometric calibration, each naming the sample or step and what was found."""
from __future__ import annotations

from goniofrost.core.errors import GoniofrostError


class CalibrationError(GoniofrostError, RuntimeError):
    """A calibration step or a sample measurement could not produce a trustworthy value."""


class MarkerError(CalibrationError):
    """The holder's ArUco markers were not found (or not the expected ones) in any frame."""


class WrongTargetError(MarkerError):
    """Markers of another target (e.g. the white card where the sample should be) were read."""


class PatchTooSmallError(MarkerError):
    """The region of interest keeps too few pixels of a colour channel (a view too grazing)."""


class MisalignedError(CalibrationError):
    """The markers were read, but far from where the camera model and the kinematics put them."""


class SaturationError(CalibrationError):
    """Even the shortest exposure of the ladder saturates pixels of the sample region."""


class UnderexposedError(CalibrationError):
    """Even the longest useful exposure leaves the sample below the minimal SNR."""
