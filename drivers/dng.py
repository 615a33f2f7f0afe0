"""Write a Bayer mosaic as a minimal DNG (tifffile) that LibRaw/rawpy reads back exactly.

Tags follow PROTOCOLS.md section 4; the frame's metadata goes into the ImageDescription as JSON,
the exposure also into EXIF ExposureTime, make, model and serial into their tags.
"""
from __future__ import annotations

import json
import os
from fractions import Fraction
from pathlib import Path

import numpy as np
import tifffile
from tifffile import DATATYPE

# CFAPattern of the 2 x 2 tile, row by row (0 = R, 1 = G, 2 = B); a camera's BayerRG is RGGB.
CFA_PATTERNS = {"RGGB": (0, 1, 1, 2), "GRBG": (1, 0, 2, 1), "GBRG": (1, 2, 0, 1), "BGGR": (2, 1, 1, 0)}
# XYZ -> camera for an idealised sensor: identity (the pipeline uses raw values only).
COLOR_MATRIX = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)


def _dng_tags(black: int, white: int, exposure_s: float, cfa: str, model: str, make: str | None,
              serial: str | None) -> list[tuple]:
    """The DNG tags that make LibRaw treat the strip as a raw Bayer mosaic."""
    exp = Fraction(exposure_s).limit_denominator(1_000_000)
    tags = [
        (50706, DATATYPE.BYTE, 4, (1, 4, 0, 0), True),        # DNGVersion
        (50707, DATATYPE.BYTE, 4, (1, 1, 0, 0), True),        # DNGBackwardVersion
        (50708, DATATYPE.ASCII, 0, model, True),              # UniqueCameraModel
        (33421, DATATYPE.SHORT, 2, (2, 2), True),             # CFARepeatPatternDim
        (33422, DATATYPE.BYTE, 4, CFA_PATTERNS[cfa], True),   # CFAPattern
        (50710, DATATYPE.BYTE, 3, (0, 1, 2), True),           # CFAPlaneColor
        (50711, DATATYPE.SHORT, 1, 1, True),                  # CFALayout: rectangular
        (50713, DATATYPE.SHORT, 2, (1, 1), True),             # BlackLevelRepeatDim
        (50714, DATATYPE.LONG, 1, int(black), True),          # BlackLevel
        (50717, DATATYPE.LONG, 1, int(white), True),          # WhiteLevel
        (50721, DATATYPE.SRATIONAL, 9, COLOR_MATRIX, True),   # ColorMatrix1
        (50778, DATATYPE.SHORT, 1, 21, True),                 # CalibrationIlluminant1: D65
        (50728, DATATYPE.RATIONAL, 3, (1, 1, 1, 1, 1, 1), True),  # AsShotNeutral
        (33434, DATATYPE.RATIONAL, 1, (exp.numerator, exp.denominator), True),  # ExposureTime
        (272, DATATYPE.ASCII, 0, model, True),                # Model
    ]
    if make:
        tags.append((271, DATATYPE.ASCII, 0, make, True))     # Make
    if serial:
        tags.append((50735, DATATYPE.ASCII, 0, serial, True))  # CameraSerialNumber
    return tags


def write_dng(path: Path, mosaic: np.ndarray, black: int, white: int, metadata: dict, *, cfa: str = "RGGB",
              model: str = "Sim Gonio Cam", make: str | None = None, serial: str | None = None) -> Path:
    """Write ``mosaic`` (H, W) uint16 with the 2 x 2 colour tile ``cfa`` (a key of CFA_PATTERNS)
    to ``path`` atomically (temp name, then rename); ``black``, ``white``: levels in DN.

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
                     extratags=_dng_tags(black, white, float(metadata["exposure_s"]), cfa, model, make, serial))
        os.replace(tmp, path)
    except BaseException:  # a full disk leaves no partial file behind
        tmp.unlink(missing_ok=True)
        raise
    return path
