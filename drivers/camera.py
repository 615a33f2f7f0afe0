"""The camera contract: capture one RAW frame of a given exposure into a file.

A capture session only ever calls ``connect``, ``capture`` and ``close``; the calibration also
asks for a target with ``set_target`` (``"sample"``, ``"white"``: the white reference card,
``"flat"``: a uniform diffuser over the lens). A real rig without motorised targets implements
``set_target`` by asking the operator (see ``FolderCamera``).
"""
from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from goniofrost.core.errors import GoniofrostError

TARGETS = ("sample", "white", "flat")


class CameraError(GoniofrostError, RuntimeError):
    """The camera failed to deliver a frame (names the camera, the exposure and the cause)."""


@dataclass
class RawFrame:
    """One captured RAW file: where it is, its exposure in seconds, what the camera reported."""

    path: Path
    exposure_s: float
    metadata: dict = field(default_factory=dict)


class Camera(ABC):
    """A camera that writes one RAW file per ``capture`` call."""

    target: str = "sample"

    @abstractmethod
    def connect(self) -> None:
        """Open the device; nothing is opened by the constructor."""

    @abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    @abstractmethod
    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        """Expose for ``exposure_s`` seconds and write the RAW file to ``path``."""

    def set_target(self, target: str) -> None:
        """Put ``target`` (one of TARGETS) in front of the camera."""
        if target not in TARGETS:
            raise CameraError(f"camera target: expected one of {TARGETS}, found {target!r}")
        self.target = target


class FolderCamera(Camera):
    """A real camera that drops RAW files into a folder (tethering software, a hot folder).

    ``trigger(exposure_s)`` starts an exposure (e.g. a gphoto2 or serial-remote call, supplied by
    the caller); the newest new file with a suffix in ``suffixes`` that appears in ``folder``
    within ``timeout_s`` is moved to the requested path. ``ask(message)`` is called when the
    calibration needs a different target in front of the lens (default: print and wait for Enter).
    """

    def __init__(self, folder, trigger: Callable[[float], None], timeout_s: float = 30.0,
                 suffixes=(".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf"),
                 ask: Callable[[str], None] | None = None, poll_s: float = 0.05) -> None:
        self.folder, self.trigger, self.timeout_s = Path(folder), trigger, float(timeout_s)
        self.suffixes = tuple(s.lower() for s in suffixes)
        self.ask = ask or (lambda msg: input(msg + " - press Enter when ready"))
        self.poll_s = poll_s

    def connect(self) -> None:
        if not self.folder.is_dir():
            raise CameraError(f"folder camera: {self.folder} is not a directory")

    def close(self) -> None:
        pass

    def set_target(self, target: str) -> None:
        if target != self.target:
            self.ask(f"put the {target!r} target in front of the camera")
        super().set_target(target)

    def _raw_files(self) -> set[Path]:
        return {p for p in self.folder.iterdir() if p.suffix.lower() in self.suffixes}

    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        before = self._raw_files()
        self.trigger(exposure_s)
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            new = self._raw_files() - before
            if new:
                src = max(new, key=lambda p: p.stat().st_mtime)
                dest = Path(path).with_suffix(src.suffix)
                src.replace(dest)
                return RawFrame(dest, float(exposure_s), {"source": str(src)})
            time.sleep(self.poll_s)
        raise CameraError(f"folder camera: no new RAW file in {self.folder} within "
                          f"{self.timeout_s} s of a {exposure_s} s exposure")
