"""The simulated devices of a rig: the one module that opens them.

A ``simulated: true`` rig file is served by ``sim.rig.SimulatedRig`` in this process; the real
drivers connect to its twins over ptys and loopback TCP. The simulated camera sees the true pose
(``simulated_pose``) and a material the caller hands in: ``spec`` (``SPEC:NAME``) and
``brdf(w_i, w_o)`` (RGB (3,) in 1/sr of unit directions (3,) in the sample frame).
``simulated_devices`` is the twins' opener for ``open_hardware``; ``rig_devices`` picks twins or
real devices by the rig file; ``device_sections`` gives the console the twins' endpoints;
``twins``, ``simulated_camera`` and ``show_material`` serve ``goniofrost sim``;
``connected_camera`` is the camera for ``rig check``.
"""
from __future__ import annotations

from contextlib import contextmanager

from goniofrost.rig.hardware import RigHardware, connected, open_camera, real_devices


def rig_devices(rig, **options):
    """``simulated_devices`` for a rig file marked ``simulated: true``, else ``real_devices``
    (``options``: material, seed, speedup): the opener the commands hand to ``open_hardware``.
    A rig file of ``goniofrost sim --write-rig`` (``rig.twins``) is opened as real devices after
    its camera service is told which material to render (``show_material``)."""
    if not rig.simulated and rig.twins:
        show_material(rig, options.get("material"))
    return (simulated_devices if rig.simulated else real_devices)(rig, **options)


def show_material(rig, material) -> None:
    """Ask the twins' camera service of ``rig`` to render ``material`` (``.spec`` or ``SPEC:NAME``;
    None: the one ``goniofrost sim`` started with); ConfigError naming ``twins.camera_service_port``
    when the service is gone or refuses it."""
    from goniofrost.core.errors import ConfigError
    from sim.camera_service import request

    spec = getattr(material, "spec", material)
    port = rig.twins["camera_service_port"]
    try:
        answer = request(port, f"material {spec or 'default'}")
    except OSError as exc:
        answer = f"error no simulated camera service on 127.0.0.1:{port} ({exc}): is goniofrost sim still running?"
    if not answer.startswith("ok"):
        raise ConfigError(rig.source, "twins.camera_service_port", f"the simulated camera to show "
                          f"{spec or 'its own material'}", answer.removeprefix("error "))


def twins(rig, *, speedup: float | None = None, seed: int = 0):
    """The rig's simulated devices (``sim.rig.SimulatedRig``), a context manager: started on
    entering, stopped on leaving; ``resolved_rig()`` names their endpoints."""
    from sim.rig import SimulatedRig

    return SimulatedRig(rig, speedup=speedup, seed=seed)


def simulated_camera(rig, simulation, material, seed: int):
    """The simulated camera of ``rig`` on the running ``simulation``, showing ``material`` (``spec``,
    ``brdf``; None: an empty stage), its noise from ``seed``; not connected yet."""
    from goniofrost.core.camera_model import CameraModel
    from planner.kinematics import arm_side
    from sim.camera import SimCamera

    pose = simulated_pose(rig)
    name, brdf = (None, None) if material is None else (material.spec, material.brdf)
    return SimCamera(name, brdf, lambda: pose(simulation.true_joints_deg()), simulation.lamp_model,
                     simulation.clock, (rig.sim or {}).get("camera", {}), seed,
                     model=CameraModel.from_section(rig.camera), arm_side=arm_side(rig))


@contextmanager
def simulated_devices(rig, *, material=None, seed: int | None = None, speedup: float | None = None):
    """Start ``rig``'s twins, connect the real drivers to them and yield a RigHardware whose
    ``simulation`` is the running SimulatedRig; ``seed`` (None: the rig's ``sim.seed``) and
    ``speedup`` (None: its ``sim.clock_speedup``) of the simulation; ``material`` what the camera shows."""
    from drivers.rig_devices import RigDevices

    sim_section = rig.sim or {}
    seed = int(sim_section.get("seed", 0) if seed is None else seed)
    with twins(rig, speedup=speedup, seed=seed) as simulation:
        simulation.start()
        devices = RigDevices.from_rig(simulation.resolved_rig())
        with connected(devices):
            camera = simulated_camera(rig, simulation, material, seed)
            camera.connect()
            with _emulated_pylon(rig, camera) as pylon_camera:
                try:
                    yield RigHardware(devices.axes, devices.lamp, pylon_camera or camera, simulation.clock,
                                      simulation, extra={} if pylon_camera is None else {"scene": pylon_camera.image_source},
                                      reconnect=devices.reconnect)
                finally:
                    camera.close()


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
    sim_camera = simulated_camera(rig, simulation, None, int((rig.sim or {}).get("seed", 0)))
    sim_camera.connect()
    try:
        with _emulated_pylon(rig, sim_camera) as pylon_camera:
            camera = pylon_camera or sim_camera
            camera.set_target("white")  # a simulated target: nothing asks the operator
            yield camera
    finally:
        sim_camera.close()


@contextmanager
def device_sections(rig, speedup: float | None = None):
    """(the rig, None) for a real rig, or (the rig with its simulated devices' endpoints, the
    SimulatedRig), started for the command (the console's devices, connected by the caller)."""
    if not rig.simulated:
        yield rig, None
        return
    with twins(rig, speedup=speedup) as simulation:
        yield simulation.resolved_rig(), simulation


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
