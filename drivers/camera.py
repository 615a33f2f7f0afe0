"""The camera contract: capture one RAW frame of a given exposure into a file.

A session calls ``connect``, ``capture`` and ``close``; the calibration also calls ``set_target``
(``"sample"``, ``"white"``, ``"flat"``), which ``FolderCamera`` implements by asking the operator
(``OperatorPrompt``).
"""
from __future__ import annotations

import os
import select
import sys
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from goniofrost.core.errors import GoniofrostError

TARGETS = ("sample", "white", "flat")
# what each target is and why it is needed: the operator's prompt says it on the line before the question
TARGET_EXPLAINED = {
    "flat": ("the 'flat' target is a uniform diffuser (opal glass or a white translucent cap) over the lens, "
             "lit by the lamp: its frames measure each pixel's gain (lens vignetting, pixel response), which "
             "every later frame is divided by"),
    "white": ("the 'white' target is the white reference card (its white tile and four markers) in the sample "
              "holder, the diffuser off the lens: its known reflectance sets the absolute scale (1/sr) of "
              "every measurement"),
    "sample": "the 'sample' target is the sample card in the holder, the diffuser off the lens: the material to measure",
}
ABORT_ANSWER = "abort"
OPERATOR_TIMEOUT_S = 600.0  # default seconds an operator has to answer (change a target, expose)


class CameraError(GoniofrostError, RuntimeError):
    """The camera failed to deliver a frame (names the camera, the exposure and the cause)."""


class OperatorAbort(CameraError):
    """The operator answered ``abort`` to a prompt (or no operator can answer: input closed)."""


class OperatorTimeout(CameraError):
    """The operator did not answer a prompt within its timeout."""


class OperatorPrompt:
    """Ask the operator to do something and wait for Enter, at most ``timeout_s`` seconds.

    ``prompt(message)`` writes ``MESSAGE - press Enter when done, or type abort`` to ``output``
    (default: standard error) and reads one line from the file descriptor ``input_fd`` (default:
    standard input, a terminal or a pipe). A line reading ``abort`` raises OperatorAbort, no
    line in time raises OperatorTimeout, closed input raises OperatorAbort; any other line
    (an empty one) means done. Lines typed before the question are discarded, so a stray Enter
    cannot confirm a target change that has not happened.
    """

    def __init__(self, timeout_s: float = OPERATOR_TIMEOUT_S, input_fd: int | None = None, output=None) -> None:
        self.timeout_s, self.input_fd, self.output = float(timeout_s), input_fd, output

    def __call__(self, message: str, why: str = "") -> None:
        """Ask ``message`` (one line; errors name it); ``why``: what it means, on the line before."""
        fd = self._input(message)
        self._discard_typeahead(fd, message)
        output = sys.stderr if self.output is None else self.output
        output.write(f"{why}\n" if why else "")
        output.write(f"{message} - press Enter when done, or type {ABORT_ANSWER}\n")
        output.flush()
        answer = self._read_line(fd, message)
        if answer.strip().lower() == ABORT_ANSWER:
            raise OperatorAbort(f"{message}: the operator answered {ABORT_ANSWER!r}")

    def _input(self, message: str) -> int:
        if self.input_fd is not None:
            return self.input_fd
        try:
            return sys.stdin.fileno()
        except (AttributeError, OSError, ValueError):  # no stdin, or one without a descriptor
            raise OperatorAbort(f"{message}: no operator can answer (no standard input)") from None

    def _discard_typeahead(self, fd: int, message: str) -> None:
        while select.select([fd], [], [], 0)[0]:
            if not os.read(fd, 4096):
                raise OperatorAbort(f"{message}: no operator can answer (standard input is closed)")

    def _read_line(self, fd: int, message: str) -> str:
        """One line from ``fd`` within the timeout (bytes up to the newline, decoded)."""
        deadline, line = time.monotonic() + self.timeout_s, b""
        while b"\n" not in line:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise OperatorTimeout(f"{message}: no answer from the operator within {self.timeout_s:g} s")
            chunk = os.read(fd, 1)  # one byte: what follows the newline stays for the next prompt to discard
            if not chunk:
                raise OperatorAbort(f"{message}: no operator can answer (standard input is closed)")
            line += chunk
        return line.decode(errors="replace")


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

    ``trigger(exposure_s)`` starts an exposure; the newest new file with a suffix in ``suffixes`` that
    appears in ``folder`` and is complete (``drivers.hot_folder``, polls ``poll_s`` apart) within
    ``timeout_s`` is taken. A file whose EXIF exposure is missing or differs from the one asked for by
    more than ``exposure_tolerance`` (relative), or that repeats an earlier frame, is refused and left
    where it is; a good one is moved to the requested path. ``ask(message, why=...)`` asks for another
    target in front of the lens (default: an ``OperatorPrompt``). ``clock()`` and ``sleep(seconds)``
    time the polls (default: the wall clock).
    """

    def __init__(self, folder, trigger: Callable[[float], None], timeout_s: float = 30.0,
                 suffixes=(".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf"),
                 ask: Callable[..., None] | None = None, poll_s: float = 0.05,
                 operator_timeout_s: float = OPERATOR_TIMEOUT_S, exposure_tolerance: float = 0.05,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        self.folder, self.trigger, self.timeout_s = Path(folder), trigger, float(timeout_s)
        self.suffixes = tuple(s.lower() for s in suffixes)
        self.ask = ask or OperatorPrompt(operator_timeout_s)
        self.poll_s = poll_s
        self.clock, self.sleep = clock, sleep
        self.exposure_tolerance = float(exposure_tolerance)
        self._taken: dict[str, Path] = {}   # content hash -> the frame it became

    def connect(self) -> None:
        if not self.folder.is_dir():
            raise CameraError(f"folder camera: {self.folder} is not a directory")

    def close(self) -> None:
        pass

    def set_target(self, target: str) -> None:
        if target != self.target:
            self.ask(f"put the {target!r} target in front of the camera", why=TARGET_EXPLAINED[target])
        super().set_target(target)

    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        from drivers.hot_folder import HotFolder

        watch = HotFolder(self.folder, self.suffixes)  # what is there before the trigger is not this frame
        self.trigger(exposure_s)
        deadline = self.clock() + self.timeout_s
        while True:
            src = watch.poll()
            if src is not None:
                return self._take(src, float(exposure_s), Path(path))
            if self.clock() >= deadline:
                raise CameraError(_no_frame(watch, self.timeout_s, exposure_s))
            self.sleep(self.poll_s)

    def _take(self, src: Path, asked_s: float, path: Path) -> RawFrame:
        """Check ``src`` (its exposure, that it is new) and move it to ``path``'s name."""
        import hashlib

        from drivers.rawfile import raw_exposure_s

        digest = hashlib.sha256(src.read_bytes()).hexdigest()
        if digest in self._taken:
            raise CameraError(f"folder camera: {src} is not new: the same file as frame {self._taken[digest]} "
                              f"(asked for {asked_s:g} s)")
        actual_s = raw_exposure_s(src)
        if actual_s is None:
            raise CameraError(f"folder camera: {src} has no exposure time (EXIF ExposureTime) to check against "
                              f"the {asked_s:g} s asked for")
        if abs(actual_s / asked_s - 1.0) > self.exposure_tolerance:
            raise CameraError(f"folder camera: {src} was exposed {actual_s:g} s (EXIF ExposureTime), asked for "
                              f"{asked_s:g} s: more than camera.exposure_tolerance {self.exposure_tolerance:g} apart")
        dest = path.with_suffix(src.suffix)
        src.replace(dest)
        self._taken[digest] = dest
        return RawFrame(dest, actual_s, {"source": str(src), "requested_exposure_s": asked_s})


def _no_frame(watch, timeout_s: float, exposure_s: float) -> str:
    """The timeout's message; it names the new files that came but never were complete."""
    head = f"within {timeout_s} s of a {exposure_s} s exposure"
    if not watch.pending():
        return f"folder camera: no new RAW file in {watch.folder} {head}"
    names = [f"{p.name} ({watch.incomplete.get(p, 'still being written')})" for p in watch.pending()]
    return f"folder camera: no complete new RAW file in {watch.folder} {head}: {', '.join(names)}"
