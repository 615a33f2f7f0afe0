"""Connect the devices of a rig for a session: ``open_hardware(rig, devices)``.

``open_hardware(rig, devices, ...)`` is a context manager yielding a ``RigHardware`` (axes, lamp,
camera, clock: the ``goniofrost.rig.contract.Hardware`` contract). The caller chooses the devices:
``real_devices`` (the default; the camera from ``open_camera``) or
``goniofrost.rig.simulated.simulated_devices`` (``rig_devices`` picks by ``simulated:``). The rig
lock (``goniofrost.rig.lock``) is held from before the first connection until the last is closed.
On leaving, whatever happened, every axis not yet confirmed stopped is stopped through the one
stop path (``goniofrost.rig.stop``) and every connection closed.
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

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
    fault drills, checkpoints), else None. ``reconnect(name)`` closes and opens one device's connection
    again (``drivers.rig_devices.RigDevices.reconnect``).
    """

    axes: dict
    lamp: object
    camera: object
    clock: object
    simulation: object = None
    extra: dict = field(default_factory=dict)
    rig_lock: object = None   # the held goniofrost.rig.lock.RigLock (its stop requests)
    pause_gate: object = None  # a server's gate the engine asks at safe points (goniofrost.server.instrument)
    reconnect: Callable | None = None  # reconnect(name): open axis ``name`` (or "lamp") again (a server's)

    @property
    def simulated(self) -> bool:
        return self.simulation is not None


@dataclass(frozen=True)
class SimOptions:
    """What the caller hands a simulated rig's opener with it: the ``material`` its camera shows
    (``spec``, ``brdf``, ``table``: ``goniofrost.datasets.shown_material``), the noise ``seed`` and
    the clock's ``speedup`` (None: the rig file's ``sim.seed``, ``sim.clock_speedup``), and
    ``on_ready(hardware)``, called once everything is connected (tests inject faults with it).
    A real rig takes none but ``on_ready``."""

    material: object = None
    seed: int | None = None
    speedup: float | None = None
    on_ready: Callable | None = None


NO_SIM = SimOptions()


@contextmanager
def open_hardware(rig, devices=None, sim: SimOptions = NO_SIM, *, program: str = "capture"):
    """Take the rig's lock for ``program``, connect ``rig``'s devices and yield a RigHardware; stop
    and close everything on exit, then release the lock (``RigInUseError`` when another program
    holds it: nothing is connected).

    ``devices(rig, material=, seed=, speedup=)``: a context manager yielding the connected
    RigHardware (None: ``real_devices``), handed ``sim``'s material, seed and speedup; ``sim.on_ready``
    is called once everything is connected. An opener with a ``rig_lock`` attribute opens devices
    whose lock its caller already holds (``goniofrost.server``): no lock is taken then.
    """
    from contextlib import nullcontext

    from goniofrost.rig.lock import rig_lock

    opener = real_devices if devices is None else devices
    held = getattr(opener, "rig_lock", None)  # an opener of devices already held (a server's) holds their lock
    locked = nullcontext(held) if held is not None else rig_lock(rig, program)
    with locked as lock, opener(rig, material=sim.material, seed=sim.seed, speedup=sim.speedup) as hardware:
        hardware.rig_lock = lock
        if sim.on_ready is not None:
            sim.on_ready(hardware)
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
            yield RigHardware(devices.axes, devices.lamp, camera, WallClock(), reconnect=devices.reconnect)
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
    """The real camera of a rig (object with ``.camera`` or the ``camera`` mapping itself), not
    connected: the class its ``kind`` names in ``drivers.rig_devices.CAMERA_CLASSES`` builds it
    (``image_source``, ``device_class``: an emulated camera's, see ``drivers.pylon``), with a
    prompt for the operator that keeps off a progress bar's line. The simulated camera is built
    from the ``sim`` section by ``goniofrost.rig.simulated``, not here.
    """
    from calib.config import validate_camera_section
    from drivers.camera import CameraError, OperatorPrompt
    from drivers.rig_devices import CAMERA_CLASSES, camera_class

    source = getattr(rig, "source", "rig file")
    section = validate_camera_section(getattr(rig, "camera", rig), source)
    if section["kind"] not in CAMERA_CLASSES:
        raise CameraError(f"camera kind {section['kind']!r}: the simulated camera is built with the "
                          f"simulated rig (goniofrost.rig.simulated), not by open_camera")
    ask = OperatorPrompt(section["operator_timeout_s"], output=BarSafeOutput())
    return camera_class(section["kind"]).from_section(section, source, ask, image_source=image_source,
                                                      device_class=device_class)
