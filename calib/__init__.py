"""Radiometric calibration as pure functions of frames: references, the adaptive exposure bracket,
HDR merge, lamp drift and the region of interest -> absolute BRDF with uncertainty. No device is
called here: the capture plan takes the frames.
"""
from .bracket import Bracket, start_index
from .config import validate_camera_section
from .errors import (CalibrationError, MarkerError, MisalignedError, PatchTooSmallError, SaturationError,
                     UnderexposedError, WrongTargetError)
from .measurement import (NotMeasured, NotMeasuredReason, SampleMeasurement, check_record, light_direction,
                          sample_measurement)
from .record import CalibrationRecord
from .references import dark_map, flat_field, flat_usable, nominal_white_pose, white_scale

__all__ = ["Bracket", "start_index", "NotMeasured", "NotMeasuredReason", "SampleMeasurement", "check_record", "light_direction", "sample_measurement",
           "CalibrationRecord", "dark_map", "flat_field", "flat_usable", "nominal_white_pose", "white_scale",
           "validate_camera_section",
           "CalibrationError", "MarkerError", "MisalignedError", "PatchTooSmallError", "SaturationError",
           "UnderexposedError", "WrongTargetError"]
