"""Write a Bayer RGGB mosaic as a minimal DNG (tifffile) that LibRaw/rawpy reads back exactly.

Tags follow ../shared/PROTOCOLS.md section 4. The frame's metadata (exposure, pose, lamp, ...)
goes into the ImageDescription as JSON and the exposure also into the EXIF ExposureTime tag.
"""
from __future__ import annotations

import json
import os
from fractions import Fraction
from pathlib import Path

import numpy as np
import tifffile
from tifffile import DATATYPE

CAMERA_MODEL = "Sim Gonio Cam"
RGGB = (0, 1, 1, 2)
# XYZ -> camera for an idealised sensor: identity (the pipeline uses raw values only).
COLOR_MATRIX = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)


def _dng_tags(black: int, white: int, exposure_s: float) -> list[tuple]:
    """The DNG tags that make LibRaw treat the strip as a raw RGGB mosaic."""
    exp = Fraction(exposure_s).limit_denominator(1_000_000)
    return [
        (50706, DATATYPE.BYTE, 4, (1, 4, 0, 0), True),        # DNGVersion
        (50707, DATATYPE.BYTE, 4, (1, 1, 0, 0), True),        # DNGBackwardVersion
        (50708, DATATYPE.ASCII, 0, CAMERA_MODEL, True),       # UniqueCameraModel
        (33421, DATATYPE.SHORT, 2, (2, 2), True),             # CFARepeatPatternDim
        (33422, DATATYPE.BYTE, 4, RGGB, True),                # CFAPattern
        (50710, DATATYPE.BYTE, 3, (0, 1, 2), True),           # CFAPlaneColor
        (50711, DATATYPE.SHORT, 1, 1, True),                  # CFALayout: rectangular
        (50713, DATATYPE.SHORT, 2, (1, 1), True),             # BlackLevelRepeatDim
        (50714, DATATYPE.LONG, 1, int(black), True),          # BlackLevel
        (50717, DATATYPE.LONG, 1, int(white), True),          # WhiteLevel
        (50721, DATATYPE.SRATIONAL, 9, COLOR_MATRIX, True),   # ColorMatrix1
        (50778, DATATYPE.SHORT, 1, 21, True),                 # CalibrationIlluminant1: D65
        (50728, DATATYPE.RATIONAL, 3, (1, 1, 1, 1, 1, 1), True),  # AsShotNeutral
        (33434, DATATYPE.RATIONAL, 1, (exp.numerator, exp.denominator), True),  # ExposureTime
    ]


def write_dng(path: Path, mosaic: np.ndarray, black: int, white: int, metadata: dict) -> Path:
    """Write ``mosaic`` (H, W) uint16 RGGB to ``path`` atomically (temp name, then rename).

    ``metadata`` must hold ``exposure_s`` and be JSON-serialisable.
    """
    path = Path(path)
    if mosaic.dtype != np.uint16 or mosaic.ndim != 2:
        raise ValueError(f"mosaic must be a 2-D uint16 array, got {mosaic.dtype} {mosaic.shape}")
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with tifffile.TiffWriter(tmp) as tw:
            tw.write(mosaic, photometric="cfa", compression=None, subfiletype=0,
                     description=json.dumps(metadata, sort_keys=True),
                     extratags=_dng_tags(black, white, float(metadata["exposure_s"])))
        os.replace(tmp, path)
    except BaseException:  # a full disk leaves no partial file behind
        tmp.unlink(missing_ok=True)
        raise
    return path
