"""The image source of pylon's emulated camera (``PYLON_CAMEMU``): the simulated holder.

Before each grab ``EmulatedScene.serve`` renders ``SimCamera.expose`` into a 16-bit TIFF and points
the emulated camera at it; the SDK does the rest. Black and white levels are in DN of the pixel
format. Drills (``arm``): ``unplug``, ``stall``.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

DRILLS = ("unplug", "stall")


class EmulatedScene:
    """Serves ``camera`` (a connected ``sim.camera.SimCamera``) through an emulated pylon camera
    of ``bits`` (12 or 16) bits per pixel."""

    def __init__(self, camera, bits: int) -> None:
        self.camera, self.bits = camera, int(bits)
        self.folder = Path(tempfile.mkdtemp(prefix="goniofrost-pylon-scene-"))
        self.served = 0                         # frames served so far
        self.armed: dict[int, str] = {}         # frame number -> drill
        self.struck: list[str] = []
        self._stall = False                     # a stall drill waits for the grab to start

    def arm(self, kind: str, at_frame: int) -> None:
        """Strike drill ``kind`` (one of DRILLS) instead of serving frame ``at_frame`` (0 = the
        first frame this scene serves)."""
        if kind not in DRILLS:
            raise ValueError(f"unknown camera drill {kind!r}; expected one of {DRILLS}")
        self.armed[int(at_frame)] = kind

    def prepare(self, device) -> None:
        """Images from a file, and the simulated sensor's black level (read by the driver)."""
        device.TestImageSelector.Value = "Off"
        device.ImageFileMode.Value = "On"
        device.BlackLevel.Value = float(self.camera.params["black_level"])

    def serve(self, device, exposure_s: float, target: str) -> None:
        """Render the frame of ``exposure_s`` (s) with ``target`` in front of the lens and load it."""
        drill = self.armed.pop(self.served, None)
        self.served += 1
        if drill is not None:
            self.struck.append(drill)
            self._strike(device, drill)
            return
        self.camera.target = target
        mosaic, _ = self.camera.expose(exposure_s)
        # the emulated camera turns a 16-bit file into the pixel format's depth by dropping low bits
        served = (mosaic.astype(np.uint32) << (16 - self.bits)).astype(np.uint16)
        path = self.folder / "frame.tiff"
        _write_tiff(path, served)
        device.ImageFilename.Value = str(path)

    def started(self, device) -> None:
        """The driver started grabbing: a stall drill stops the acquisition now, so the trigger the
        driver sends next is never answered (starting the grab would have restarted it)."""
        if self._stall:
            self._stall = False
            device.AcquisitionStop.Execute()

    def _strike(self, device, drill: str) -> None:
        if drill == "unplug":
            device.FirePnPCallback.Execute()
        else:
            self._stall = True

    def close(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def _write_tiff(path: Path, image: np.ndarray) -> None:
    """A 16-bit single-channel TIFF written under a temporary name, then renamed."""
    import tifffile

    tmp = path.with_name(f".{path.name}.tmp")
    tifffile.imwrite(tmp, image, photometric="minisblack")
    os.replace(tmp, path)
