"""Radiometric calibration: dark frames, flat field, HDR from exposure brackets, white
reference, lamp drift and the ArUco region of interest -> absolute BRDF with uncertainty."""
from .calibrator import Calibrator, SampleMeasurement
from .config import validate_camera_section
from .open_camera import open_camera
from .errors import CalibrationError, MarkerError, SaturationError, UnderexposedError, WrongTargetError
from .record import CalibrationRecord

__all__ = ["Calibrator", "SampleMeasurement", "CalibrationRecord", "validate_camera_section", "open_camera",
           "CalibrationError", "MarkerError", "SaturationError", "UnderexposedError", "WrongTargetError"]
