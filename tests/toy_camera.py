"""A toy camera kind for tests/test_extend.py: the one file a new camera kind needs.

Kind ``toy``: every frame is a uniform grey DNG at ``toy_level`` (a fraction of the white level)
times the exposure in seconds, clipped at white; ``toy_level`` is its own key of the rig file's
``camera:`` section.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.camera import Camera, RawFrame
from drivers.dng import write_dng
from goniofrost.core.config_check import Key, is_number

BLACK, WHITE = 64, 4095


class ToyCamera(Camera):
    """Uniform frames of ``level`` x exposure (s) of the white level, ``image_size`` (width, height) px."""

    KEYS = {"toy_level": Key(lambda v: is_number(v) and 0 < v <= 100, "a number in (0, 100] (white per second)", 1.0)}

    @classmethod
    def from_section(cls, section: dict, source, ask, **_emulation) -> "ToyCamera":
        return cls(section["toy_level"], section["intrinsics"]["image_size_px"])

    def __init__(self, level: float, image_size) -> None:
        self.level, self.image_size, self.connected = float(level), tuple(image_size), False

    def connect(self) -> None:
        self.connected = True

    def close(self) -> None:
        self.connected = False

    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        value = BLACK + min(1.0, self.level * exposure_s) * (WHITE - BLACK)
        mosaic = np.full(self.image_size[::-1], round(value), dtype=np.uint16)
        dest = write_dng(Path(path).with_suffix(".dng"), mosaic, BLACK, WHITE, {"exposure_s": exposure_s})
        return RawFrame(dest, exposure_s)
