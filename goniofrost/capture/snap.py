"""Take one frame, or one bracket, at the current pose with whatever camera the rig has.

For tools that look through the camera outside a capture session (the console's ``rig snap``, a
focus check): the frames go through the session's own executor (``capture.executor.
StepExecutor``) on a ``capture.contract.Hardware``, so the simulated camera, pylon's, a pylon
camera's emulation and the folder camera of a DSLR all answer the same way, each frame with the
exposure the camera really took (read back) and its decoded RAW image. Nothing moves here.
"""
from __future__ import annotations

from pathlib import Path


def snap_frame(hardware, folder, exposure_s: float, name: str = "snap.dng"):
    """One frame of ``exposure_s`` seconds into FOLDER/NAME; return its ``capture.steps.Frame``
    (``path``, ``exposure_s`` as taken, ``raw``: drivers.rawfile.RawImage, ``lamp_relative``)."""
    from goniofrost.capture.executor import StepExecutor
    from goniofrost.capture.steps import Expose

    return StepExecutor(hardware, Path(folder))(Expose(float(exposure_s), name))


def snap_bracket(hardware, folder, exposures_s, stem: str = "snap") -> list:
    """One frame per exposure of ``exposures_s`` (s), shortest first, into FOLDER/STEM_e<i>.dng;
    return their Frames (each with the exposure the camera took)."""
    return [snap_frame(hardware, folder, t, f"{stem}_e{i}.dng") for i, t in enumerate(sorted(exposures_s))]
