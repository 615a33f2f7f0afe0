"""Connect the devices of a rig for a session: ``open_hardware(rig, devices)``.

``open_hardware(rig, devices, ...)`` is a context manager yielding a ``RigHardware`` (axes, lamp,
camera, clock: the ``goniofrost.rig.contract.Hardware`` contract). Whoever calls it chooses the
devices: ``real_devices`` (the default: the drivers connect to the rig's hardware, its camera from
``open_camera``) or ``goniofrost.rig.simulated.simulated_devices`` (the simulated twins, which speak
the real protocols; ``goniofrost.rig.simulated.rig_devices`` picks by the rig file's
``simulated:``). The rig's lock (``goniofrost.rig.lock``: one program drives a rig at a time) is
held from before the first device is connected until every connection is closed. On leaving, every
axis not yet confirmed stopped is told to stop (through the one stop path, ``goniofrost.rig.stop``,
which confirms each; its findings are logged to the session's device log) and every connection
closed, whatever happened: after a fault, whose stop the engine confirmed, each axis is stopped once.
"""
from __future__ import annotations

import logging
import shlex
import subprocess
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

log = logging.getLogger(__name__)


class WallClock:
    """Real seconds (a real rig's session clock)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


@dataclass
class RigHardware:
    """What the session engine drives (``goniofrost.rig.contract.Hardware``).

    ``simulation`` is the running simulation on a simulated rig (``goniofrost.rig.contract.Simulation``:
    fault drills, checkpoints), else None.
    """

    axes: dict
    lamp: object
    camera: object
    clock: object
    simulation: object = None
    extra: dict = field(default_factory=dict)
    rig_lock: object = None   # the held goniofrost.rig.lock.RigLock (its stop requests)

    @property
    def simulated(self) -> bool:
        return self.simulation is not None


@contextmanager
def open_hardware(rig, devices=None, *, material=None, seed: int | None = None, speedup: float | None = None,
                  on_ready=None, program: str = "capture"):
    """Take the rig's lock for ``program``, connect ``rig``'s devices and yield a RigHardware; stop
    and close everything on exit, then release the lock (``RigInUseError`` when another program
    holds it: nothing is connected).

    ``devices(rig, material=, seed=, speedup=)``: a context manager yielding the connected
    RigHardware (None: ``real_devices``). ``material`` (what a simulated camera shows: ``.spec``,
    ``.brdf``), ``seed`` and ``speedup`` are handed to it. ``on_ready(hardware)`` (optional) is
    called once everything is connected (tests use it to inject faults into the simulated devices).
    """
    from goniofrost.rig.lock import rig_lock

    opener = real_devices if devices is None else devices
    with rig_lock(rig.name, program) as lock, opener(rig, material=material, seed=seed, speedup=speedup) as hardware:
        hardware.rig_lock = lock
        if on_ready is not None:
            on_ready(hardware)
        yield hardware


@contextmanager
def real_devices(rig, *, material=None, seed=None, speedup=None):
    """The real devices of ``rig``, connected (``material``, ``seed``, ``speedup``: a simulated
    rig's only, refused before this by the commands). A rig file marked ``simulated: true`` names
    no real endpoints: GoniofrostError, nothing connected."""
    from drivers.rig_devices import RigDevices
    from goniofrost.core.errors import GoniofrostError

    if rig.simulated:
        raise GoniofrostError(f"{rig.source}: rig {rig.name!r} is simulated (simulated: true): its devices are "
                              f"opened by goniofrost.rig.simulated, not as real devices")
    devices = RigDevices.from_rig(rig)
    with connected(devices):
        camera = open_camera(rig)
        camera.connect()
        try:
            yield RigHardware(devices.axes, devices.lamp, camera, WallClock())
        finally:
            camera.close()


@contextmanager
def connected(devices):
    """connect_all, then on any exit stop every axis not yet confirmed stopped (``release_stop``:
    what it could not confirm is logged) and close every connection."""
    from goniofrost.rig.stop import release_stop

    devices.connect_all()
    try:
        yield devices
    finally:
        for action in (lambda: release_stop(devices.axes), devices.close_all):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - keep closing; the session's own error matters more
                log.warning("while releasing the rig: %s", exc)


class BarSafeOutput:
    """Standard error for the operator's prompts that never writes into a progress bar's line: the
    bar (tqdm) is cleared, the prompt printed on its own lines, the bar drawn again below it."""

    def write(self, text: str) -> None:
        import sys

        from tqdm import tqdm

        if text:
            tqdm.write(text, file=sys.stderr, end="")

    def flush(self) -> None:
        import sys

        sys.stderr.flush()


def open_camera(rig, *, image_source=None, device_class: str | None = None):
    """The real camera of a rig (object with ``.camera`` or the ``camera`` mapping itself): a
    ``drivers.pylon.PylonCamera`` for ``kind: pylon`` (``image_source``, ``device_class``: an
    emulated camera's, see there), else a FolderCamera.

    ``trigger_command`` (e.g. ``gphoto2 --set-config shutterspeed={shutter} --capture-image-and-download
    --filename {folder}/%Y%m%d-%H%M%S-%n.%C``) is run for each exposure with ``{shutter}`` the
    camera's own label (from ``shutter_speeds``), ``{exposure_s}`` the seconds and ``{folder}``
    the watched folder; without it the operator is asked to expose (and, always, to change the
    target), with ``operator_timeout_s`` to answer and ``abort`` as a way out. ``target_command``
    (``{target}``: sample, white, flat) changes the target in front of the lens; without it the
    operator is asked. The simulated camera is built from the ``sim`` section by
    ``goniofrost.rig.simulated``, not here.
    """
    from calib.config import validate_camera_section
    from drivers.camera import CameraError, OperatorPrompt
    from goniofrost.core.errors import ConfigError

    source = getattr(rig, "source", "rig file")
    section = validate_camera_section(getattr(rig, "camera", rig), source)
    if section["kind"] == "pylon":
        from drivers.pylon import PylonCamera

        return PylonCamera(section["serial"], section["pixel_format"], section["gain_db"], section["exposures_s"],
                           section["intrinsics"]["image_size_px"], section["timeout_s"], device_class=device_class,
                           image_source=image_source,
                           ask=OperatorPrompt(section["operator_timeout_s"], output=BarSafeOutput()), source=source)
    if section["kind"] != "rawfile":
        raise CameraError(f"camera kind {section['kind']!r}: the simulated camera is built with the "
                          f"simulated rig (goniofrost.rig.simulated), not by open_camera")
    if section["folder"] is None:
        raise ConfigError(source, "camera.folder", "the folder the camera writes RAW files to (kind rawfile)", "nothing")
    prompt = OperatorPrompt(section["operator_timeout_s"], output=BarSafeOutput())
    timeout_s = section["timeout_s"]
    command, target_command = section["trigger_command"], section.get("target_command")
    labels = section["shutter_speeds"]
    if command is None:
        def trigger(exposure_s: float) -> None:
            speed = f"{exposure_s} s" if not labels else f"{_shutter(labels, exposure_s)} ({exposure_s:g} s)"
            prompt(f"expose one RAW frame of {speed} into {section['folder']}")
    else:
        def trigger(exposure_s: float) -> None:
            _run_camera_command(command.format(exposure_s=exposure_s, shutter=_shutter(labels, exposure_s),
                                               folder=section["folder"]),
                                "camera trigger", "camera.timeout_s", timeout_s)
    change_target = None if target_command is None else (
        lambda target: _run_camera_command(target_command.format(target=target), "camera target",
                                           "camera.timeout_s", timeout_s))
    return _TargetFolderCamera(section["folder"], trigger, timeout_s=timeout_s, ask=prompt,
                               change_target=change_target, exposure_tolerance=section["exposure_tolerance"])


def _run_camera_command(text: str, what: str, key: str, timeout_s: float) -> None:
    """Run one camera command line; CameraError naming it when it fails or outlasts ``timeout_s``."""
    from drivers.camera import CameraError

    args = shlex.split(text)
    try:
        done = subprocess.run(args, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise CameraError(f"{what} {args[0]!r} did not finish within {timeout_s:g} s ({key})") from None
    except OSError as exc:
        raise CameraError(f"{what} {args[0]!r} cannot run: {exc}") from None
    if done.returncode != 0:
        raise CameraError(f"{what} {args[0]!r} failed ({done.returncode}): {done.stderr.strip()[:200]}")


def _TargetFolderCamera(folder, trigger, *, timeout_s, ask, change_target, exposure_tolerance=0.05):
    """A FolderCamera; with ``change_target(target)`` its targets are changed by that (a command)
    instead of asking the operator."""
    from drivers.camera import Camera, FolderCamera

    if change_target is None:
        return FolderCamera(folder, trigger, timeout_s=timeout_s, ask=ask, exposure_tolerance=exposure_tolerance)

    class CommandTargets(FolderCamera):
        commanded = False  # a new process does not know what the last one left in front of the lens

        def set_target(self, target: str) -> None:
            if target != self.target or not self.commanded:
                change_target(target)
                self.commanded = True
            Camera.set_target(self, target)  # checks the name; no operator prompt

    return CommandTargets(folder, trigger, timeout_s=timeout_s, ask=ask, exposure_tolerance=exposure_tolerance)


def _shutter(labels, exposure_s: float) -> str:
    """The camera's own label of an exposure: from its ``shutter_speeds``, else 1/N below a second."""
    from fractions import Fraction

    from calib.config import shutter_label

    if labels:
        return shutter_label(labels, exposure_s)
    fraction = Fraction(exposure_s).limit_denominator(100_000)
    return f"1/{fraction.denominator}" if exposure_s < 1 and fraction.numerator == 1 else f"{exposure_s:g}"
