"""Connect the devices of a rig for a session: a simulated rig's own devices, or a real rig's.

``open_hardware(rig, ...)`` is a context manager yielding a ``RigHardware`` (axes, lamp,
camera, clock: the ``goniofrost.capture.contract.Hardware`` contract). A rig marked
``simulated: true`` starts ``sim.rig.SimulatedRig`` in this process: its devices speak the real
protocols over pseudo-terminals and loopback TCP, and the real drivers connect to them exactly as
to hardware. The simulated camera sees the pose through forward kinematics of the simulated
axes' true positions. A real rig's camera comes from ``open_camera``. The rig's lock
(``goniofrost.capture.rig_lock``: one program drives a rig at a time) is held from before the
first device is connected until every connection is closed. On leaving, every axis not yet
confirmed stopped is told to stop (through the engine's one stop path, which confirms each; its
findings are logged to the session's device log) and every connection closed, whatever
happened: after a fault, whose stop the engine confirmed, each axis is stopped once.
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


@dataclass
class RigHardware:
    """What the session engine drives (``goniofrost.capture.contract.Hardware``).

    ``simulation`` is the running ``SimulatedRig`` on a simulated rig (for fault injection and
    ground truth), else None.
    """

    axes: dict
    lamp: object
    camera: object
    clock: object
    simulation: object = None
    extra: dict = field(default_factory=dict)
    rig_lock: object = None   # the held goniofrost.capture.rig_lock.RigLock (its stop requests)

    @property
    def simulated(self) -> bool:
        return self.simulation is not None


@contextmanager
def open_hardware(rig, *, material: str | None = None, seed: int | None = None, speedup: float | None = None,
                  on_ready=None, program: str = "capture"):
    """Take the rig's lock for ``program``, connect ``rig``'s devices and yield a RigHardware; stop
    and close everything on exit, then release the lock (``RigInUseError`` when another program
    holds it: nothing is connected).

    ``on_ready(hardware)`` (optional) is called once everything is connected (tests use it to
    inject faults into the simulated devices).
    """
    from goniofrost.capture.rig_lock import rig_lock

    opener = _simulated if rig.simulated else _real
    with rig_lock(rig.name, program) as lock, opener(rig, material=material, seed=seed, speedup=speedup) as hardware:
        hardware.rig_lock = lock
        if on_ready is not None:
            on_ready(hardware)
        yield hardware


@contextmanager
def _simulated(rig, *, material, seed, speedup):
    from drivers.rig_devices import RigDevices
    from goniofrost.datasets import material_brdf
    from sim.rig import SimulatedRig

    seed = int((rig.sim or {}).get("seed", 0) if seed is None else seed)
    name, brdf = material_brdf(material) if material is not None else (None, None)
    with SimulatedRig(rig, speedup=speedup, seed=seed) as simulation:
        simulation.start()
        devices = RigDevices.from_rig(simulation.resolved_rig())
        with _connected(devices):
            camera = simulated_camera(rig, simulation, name, brdf, seed)
            camera.connect()
            with _emulated_pylon(rig, camera) as pylon_camera:
                try:
                    yield RigHardware(devices.axes, devices.lamp, pylon_camera or camera, simulation.clock,
                                      simulation, extra={} if pylon_camera is None else {"scene": pylon_camera.image_source})
                finally:
                    camera.close()


def simulated_camera(rig, simulation, name: str | None, brdf, seed: int):
    """The simulated camera (not connected) of a simulated rig showing material ``name`` (its
    BRDF function ``brdf``; None: no material, the white card only) at the running
    ``simulation``'s true axis positions."""
    from goniofrost.core.camera_model import CameraModel
    from planner.kinematics import arm_side
    from sim.camera import SimCamera

    pose = simulated_pose(rig)
    return SimCamera(name, brdf, lambda: pose(simulation.true_joints_deg()), simulation.lamp_model, simulation.clock,
                     (rig.sim or {}).get("camera", {}), seed, model=CameraModel.from_section(rig.camera),
                     arm_side=arm_side(rig))


@contextmanager
def connected_camera(rig, simulation=None):
    """The rig's camera, connected, closed on exit (``rig check``): the real one (``open_camera``),
    or on a simulated rig (``simulation``: its running SimulatedRig) the simulated camera, or
    pylon's emulated camera serving it, facing the white card (no material needed). A camera
    that fails to connect raises its own error."""
    if simulation is None:
        camera = open_camera(rig)
        camera.connect()
        try:
            yield camera
        finally:
            camera.close()
        return
    sim_camera = simulated_camera(rig, simulation, None, None, int((rig.sim or {}).get("seed", 0)))
    sim_camera.connect()
    try:
        with _emulated_pylon(rig, sim_camera) as pylon_camera:
            camera = pylon_camera or sim_camera
            camera.set_target("white")  # a simulated target: nothing asks the operator
            yield camera
    finally:
        sim_camera.close()


@contextmanager
def _emulated_pylon(rig, sim_camera):
    """On a simulated rig whose camera is ``kind: pylon``: the real pylon driver on pylon's emulated
    camera, which serves the simulated camera's frames (``sim.pylon_scene``); else None."""
    import os

    if (rig.camera or {}).get("kind") != "pylon":
        yield None
        return
    from goniofrost.core.errors import ConfigError
    from sim.pylon_scene import EmulatedScene

    bits = int(str(rig.camera.get("pixel_format", "BayerRG12"))[-2:])
    if sim_camera.params["white_level"] > 2 ** bits - 1:  # the served mosaic would wrap around
        raise ConfigError(rig.source, "sim.camera.white_level", f"at most {2 ** bits - 1} (the {bits}-bit "
                          f"camera.pixel_format)", sim_camera.params["white_level"])
    os.environ.setdefault("PYLON_CAMEMU", "1")  # read by pylon when it enumerates its devices
    scene = EmulatedScene(sim_camera, bits)
    try:
        camera = open_camera(rig, image_source=scene, device_class="BaslerCamEmu")
        camera.connect()
        try:
            yield camera
        finally:
            camera.close()
    finally:
        scene.close()


def simulated_pose(rig):
    """``pose(encoder_deg) -> (w_i, w_o)``: the light and view directions the simulated camera
    really sees at the simulated axes' encoder positions (degrees by axis name): the rig as built,
    with its ``sim.misalignment_deg`` and without whatever alignment the session believes in."""
    import dataclasses

    from planner.kinematics import forward
    from sim.misalignment import physical_joints

    built = dataclasses.replace(rig, alignment=None)
    errors = dict((rig.sim or {}).get("misalignment_deg", {}))   # checked by sim.config with the rig
    return lambda encoder_deg: forward(built, physical_joints(encoder_deg, errors))


@contextmanager
def _real(rig, *, material, seed, speedup):
    from drivers.rig_devices import RigDevices

    devices = RigDevices.from_rig(rig)
    if rig.twins:  # a rig file of `goniofrost sim --write-rig`: its camera service renders the material
        _show_material(rig, material)
    with _connected(devices):
        camera = open_camera(rig)
        camera.connect()
        try:
            yield RigHardware(devices.axes, devices.lamp, camera, WallClock())
        finally:
            camera.close()


def _show_material(rig, material: str | None) -> None:
    """Ask the twins' camera service to render ``material`` (None: the one it started with)."""
    from goniofrost.core.errors import ConfigError
    from sim.camera_service import request

    port = rig.twins["camera_service_port"]
    try:
        answer = request(port, f"material {material or 'default'}")
    except OSError as exc:
        answer = f"error no simulated camera service on 127.0.0.1:{port} ({exc}): is goniofrost sim still running?"
    if not answer.startswith("ok"):
        raise ConfigError(rig.source, "twins.camera_service_port", f"the simulated camera to show "
                          f"{material or 'its own material'}", answer.removeprefix("error "))


@contextmanager
def _connected(devices):
    """connect_all, then on any exit stop every axis not yet confirmed stopped (``release_stop``:
    what it could not confirm is logged) and close every connection."""
    from goniofrost.capture.executor import release_stop

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
    operator is asked. The simulated camera is built by the session from the ``sim`` section, not here.
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
                          f"simulated rig (sim.camera.SimCamera), not by open_camera")
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
