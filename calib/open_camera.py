"""Build the camera a real rig file describes (``camera.kind: rawfile`` -> FolderCamera)."""
from __future__ import annotations

import shlex
import subprocess

from drivers.camera import Camera, CameraError, FolderCamera, OperatorPrompt
from goniofrost.core.errors import ConfigError

from .config import validate_camera_section


def open_camera(rig) -> Camera:
    """A FolderCamera for a rig (object with ``.camera`` or the ``camera`` mapping itself).

    ``trigger_command`` (e.g. ``gphoto2 --set-config shutterspeed={exposure_s} --trigger-capture``)
    is run for each exposure; without it the operator is asked to expose (and, always, to change
    the target), with ``operator_timeout_s`` to answer and ``abort`` as a way out. The simulated
    camera is built by the session from the ``sim`` section, not here.
    """
    source = getattr(rig, "source", "rig file")
    section = validate_camera_section(getattr(rig, "camera", rig), source)
    if section["kind"] != "rawfile":
        raise CameraError(f"camera kind {section['kind']!r}: the simulated camera is built with the "
                          f"simulated rig (sim.camera.SimCamera), not by open_camera")
    if section["folder"] is None:
        raise ConfigError(source, "camera.folder", "the folder the camera writes RAW files to (kind rawfile)", "nothing")
    command, prompt = section["trigger_command"], OperatorPrompt(section["operator_timeout_s"])
    if command is None:
        def trigger(exposure_s: float) -> None:
            prompt(f"expose one RAW frame of {exposure_s} s into {section['folder']}")
    else:
        def trigger(exposure_s: float) -> None:
            args = shlex.split(command.format(exposure_s=exposure_s))
            try:
                done = subprocess.run(args, capture_output=True, text=True, timeout=section["timeout_s"])
            except subprocess.TimeoutExpired:
                raise CameraError(f"camera trigger {args[0]!r} did not finish within {section['timeout_s']:g} s "
                                  f"(camera.timeout_s)") from None
            if done.returncode != 0:
                raise CameraError(f"camera trigger {args[0]!r} failed ({done.returncode}): {done.stderr.strip()[:200]}")
    return FolderCamera(section["folder"], trigger, timeout_s=section["timeout_s"], ask=prompt)
