"""Camera kind ``rawfile``: a camera whose tethering software drops RAW files into a folder.

``trigger_command`` runs per exposure with ``{shutter}``, ``{exposure_s}`` and ``{folder}``;
``target_command`` with ``{target}``; without them the operator is asked. ``KEYS`` are the
``camera:`` keys only this kind reads; ``from_section`` builds it.
"""
from __future__ import annotations

import math
import shlex
import subprocess

from goniofrost.core.config_check import Key, is_number

from .camera import Camera, CameraError, FolderCamera


def shutter_seconds(label) -> float | None:
    """Seconds of a camera's shutter speed label ("1/4000", "0.3", "30", "2.5s"); None if it is not one."""
    if not isinstance(label, str):
        return None
    text = label.strip().removesuffix("s").strip()
    num, _, den = text.partition("/")
    try:
        value = float(num) / (float(den) if den else 1.0)
    except (ValueError, ZeroDivisionError):
        return None
    return value if 0 < value < float("inf") else None


def shutter_label(labels: list, exposure_s: float) -> str:
    """The label among ``labels`` (a camera's shutter speeds) whose seconds are ``exposure_s``
    (a rung of a ladder moved onto them), else the nearest in stops."""
    return min(labels, key=lambda x: abs(math.log(shutter_seconds(x) / exposure_s)))


class TetheredCamera(FolderCamera):
    """A FolderCamera triggered by a command (or the operator); with ``change_target(target)`` its
    targets are changed by that (a command) instead of asking the operator."""

    KEYS = {
        # the folder the camera's tethering software writes RAW files to, and the command that
        # triggers one exposure ({exposure_s} is replaced); without it the operator is asked
        "folder": Key(lambda v: v is None or (isinstance(v, str) and v != ""), "a folder path", None),
        "trigger_command": Key(lambda v: v is None or (isinstance(v, str) and ("{exposure_s}" in v or "{shutter}" in v)),
                               "a command containing {exposure_s} or {shutter} (and optionally {folder})", None),
        # command that puts a target in front of the lens ({target}: sample, white or flat), for a motorised
        # target changer (or the simulated camera of `goniofrost sim --write-rig`); without it the operator is asked
        "target_command": Key(lambda v: v is None or (isinstance(v, str) and "{target}" in v),
                              "a command containing {target}", None),
        # the camera's own shutter speeds (its labels, e.g. ["1/4000", "1/2000", ..., "30"]): each
        # exposures_s rung becomes the nearest of them and the trigger gets its label as {shutter}
        "shutter_speeds": Key(lambda v: v is None or (isinstance(v, list) and len(v) >= 1
                                                      and all(shutter_seconds(x) is not None for x in v)),
                              'a list of shutter speed labels such as "1/4000", "0.3", "30"', None),
        # a RAW file's own exposure (EXIF ExposureTime) may differ from the one asked for by this
        # fraction at most, else it is refused
        "exposure_tolerance": Key(lambda v: is_number(v) and 0 <= v < 0.5, "a number in [0, 0.5) (relative)", 0.05),
    }

    def __init__(self, folder, trigger, *, change_target=None, **options) -> None:
        super().__init__(folder, trigger, **options)
        self.change_target = change_target
        self.commanded = False  # a new process does not know what the last one left in front of the lens

    @classmethod
    def from_section(cls, section: dict, source, ask, **_emulation) -> "TetheredCamera":
        """The camera of a checked ``camera:`` section; ``ask``: the operator's prompt."""
        timeout_s, labels, folder = section["timeout_s"], section["shutter_speeds"], section["folder"]
        command, target_command = section["trigger_command"], section.get("target_command")
        if command is None:
            def trigger(exposure_s: float) -> None:
                speed = f"{exposure_s} s" if not labels else f"{_shutter(labels, exposure_s)} ({exposure_s:g} s)"
                ask(f"expose one RAW frame of {speed} into {folder}")
        else:
            def trigger(exposure_s: float) -> None:
                _run_camera_command(command.format(exposure_s=exposure_s, shutter=_shutter(labels, exposure_s),
                                                   folder=folder), "camera trigger", "camera.timeout_s", timeout_s)
        change_target = None if target_command is None else (
            lambda target: _run_camera_command(target_command.format(target=target), "camera target",
                                               "camera.timeout_s", timeout_s))
        return cls(folder, trigger, timeout_s=timeout_s, ask=ask, change_target=change_target,
                   exposure_tolerance=section["exposure_tolerance"])

    def set_target(self, target: str) -> None:
        if self.change_target is None:
            return super().set_target(target)
        if target != self.target or not self.commanded:
            self.change_target(target)
            self.commanded = True
        Camera.set_target(self, target)  # checks the name; no operator prompt


def _run_camera_command(text: str, what: str, key: str, timeout_s: float) -> None:
    """Run one camera command line; CameraError naming it when it fails or outlasts ``timeout_s``."""
    args = shlex.split(text)
    try:
        done = subprocess.run(args, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise CameraError(f"{what} {args[0]!r} did not finish within {timeout_s:g} s ({key})") from None
    except OSError as exc:
        raise CameraError(f"{what} {args[0]!r} cannot run: {exc}") from None
    if done.returncode != 0:
        raise CameraError(f"{what} {args[0]!r} failed ({done.returncode}): {done.stderr.strip()[:200]}")


def _shutter(labels, exposure_s: float) -> str:
    """The camera's own label of an exposure: from its ``shutter_speeds``, else 1/N below a second."""
    from fractions import Fraction

    if labels:
        return shutter_label(labels, exposure_s)
    fraction = Fraction(exposure_s).limit_denominator(100_000)
    return f"1/{fraction.denominator}" if exposure_s < 1 and fraction.numerator == 1 else f"{exposure_s:g}"
