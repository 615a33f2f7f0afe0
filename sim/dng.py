"""The simulated camera's DNG files: ``drivers.dng.write_dng`` with its model name and RGGB tile."""
from __future__ import annotations

from drivers.dng import COLOR_MATRIX, write_dng  # noqa: F401 - the writer the simulated camera uses

CAMERA_MODEL = "Sim Gonio Cam"
RGGB = (0, 1, 1, 2)
