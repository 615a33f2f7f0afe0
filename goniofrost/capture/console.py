"""The operator's console: read, move, home and stop a rig's axes and switch its lamp, by hand.

Each command is a short plan of the session's own steps (``Home``, ``Move``, ``LampOn``,
``LampOff``) run on the connected devices by the engine core (``plan_runner.PlanRunner``, without
a journal) and its one stop path (``goniofrost.rig.stop.stop_axes``): on any failure, Ctrl-C or a stop
request every axis is stopped and confirmed, axis by axis, and the lamp switched off. Every
command holds the rig lock while it is connected (``rig_lock``: one program drives a device at a
time). Targets are checked against the soft limits and the rig's geometry before anything is
connected, so a refused move sends no byte.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterable, Mapping

from goniofrost.core.errors import GoniofrostError
from goniofrost.capture.steps import Home, LampOff, LampOn, Move


class ConsoleError(GoniofrostError):
    """A console command that cannot be carried out as asked (nothing was moved)."""


# ----- targets ------------------------------------------------------------------------------
def parse_targets(words: Iterable[str], rig) -> dict[str, float]:
    """``["camera_arm=90", "sample_tilt=-5.5"]`` -> {axis: degrees}; ConsoleError naming the word."""
    targets: dict[str, float] = {}
    for word in words:
        name, sep, value = word.partition("=")
        if not sep or not name:
            raise ConsoleError(f"{word!r}: expected AXIS=DEGREES, e.g. {next(iter(rig.axes))}=10")
        if name not in rig.axes:
            raise ConsoleError(f"{word!r}: no axis {name!r} in {rig.source} (axes: {', '.join(rig.axes)})")
        try:
            deg = float(value)
        except ValueError:
            raise ConsoleError(f"{word!r}: {value!r} is not a number of degrees") from None
        if not math.isfinite(deg):
            raise ConsoleError(f"{word!r}: {value!r} is not a finite number of degrees")
        if name in targets:
            raise ConsoleError(f"{word!r}: axis {name} is given twice")
        targets[name] = deg
    if not targets:
        raise ConsoleError("no target: give AXIS=DEGREES (one or more)")
    return targets


def check_targets(rig, targets: Mapping[str, float]) -> None:
    """Refuse a target outside its axis's soft limits or the rig's geometry (ConsoleError naming the
    axis, the target, the limit and why)."""
    from planner.rig import Role

    for name, deg in targets.items():
        spec = rig.axes[name]
        lo, hi = spec.limits_deg
        # the target to 10 digits: at 6 ("{:g}") sample_yaw=-180.00001 read "target -180 deg is
        # outside its limits [-180, 180]"
        if not lo <= deg <= hi:
            raise ConsoleError(f"{name}: target {deg:.10g} deg is outside its limits [{lo:g}, {hi:g}] deg "
                               f"(axes.{name}.limits_deg of {rig.source}); nothing was moved")
        if spec.role is Role.SAMPLE_TILT and abs(deg) > rig.geometry.tilt_limit_deg:
            raise ConsoleError(f"{name}: target {deg:.10g} deg is beyond the stage's tilt limit "
                               f"+-{rig.geometry.tilt_limit_deg:g} deg (geometry.tilt_limit_deg); nothing was moved")
        if spec.role is Role.CAMERA_ARM and abs(deg) < rig.geometry.min_arm_separation_deg:
            raise ConsoleError(f"{name}: target {deg:.10g} deg brings the camera closer to the lamp than "
                               f"{rig.geometry.min_arm_separation_deg:g} deg (geometry.min_arm_separation_deg); "
                               f"nothing was moved")


def check_referenced(rig, axes: Mapping, names: Iterable[str]) -> None:
    """Refuse a move of an axis whose device refuses moves until it is homed (``Axis.referenced``):
    ConsoleError naming every such axis of ``names``, read before any axis moves, so the others do
    not start a move the stage would then refuse mid-way."""
    unreferenced = [name for name in names if not axes[name].referenced()]
    if unreferenced:
        fresh = (" (on a simulated rig file every command starts its devices afresh: rehearse with the twins "
                 "of goniofrost sim --write-rig)") if rig.simulated else ""
        raise ConsoleError(f"{', '.join(unreferenced)}: not homed, and the device refuses moves until it is: "
                           f"run goniofrost rig home --rig {rig.source} first{fresh}; nothing was moved")


# ----- the plans ------------------------------------------------------------------------------
def move_plan(rig, targets: Mapping[str, float]):
    """Move the named axes together (in the rig's joint order) to ``targets`` (degrees)."""
    order = [name for name in rig.joint_names if name in targets]
    reached = yield Move(None, tuple((name, float(targets[name])) for name in order))
    return reached


def home_plan(axes: Iterable[str]):
    """Home the named axes together."""
    reached = yield Home(tuple(axes))
    return reached


def lamp_plan(on: bool):
    """Switch the lamp on (returns the photodiode's reading) or off."""
    reading = yield (LampOn() if on else LampOff())
    return reading


def run_plan(hardware, plan, program: str):
    """Run a console plan on ``hardware`` through the engine core (``PlanRunner``, no journal): on
    any failure, Ctrl-C or a stop request every axis is stopped and confirmed and the lamp switched
    off, and ``SessionFault`` / ``SessionInterrupted`` say axis by axis what was confirmed."""
    from goniofrost.capture.plan_runner import PlanRunner

    return PlanRunner(hardware, ".", program=program).execute_plan(plan)


# ----- connecting --------------------------------------------------------------------------------
@dataclass
class ConsoleHardware:
    """The connected axes and lamp of a rig, for the console (no camera, the wall clock)."""

    axes: dict
    lamp: object
    clock: object
    simulated: bool = False
    simulation: object = None
    camera: object = None
    rig_lock: object = None


@contextmanager
def connected_rig(rig, *, enable: bool, program: str, speedup: float | None = None, sections=None):
    """Take the rig lock for ``program``, connect every axis (enabled when ``enable``) and the lamp
    of ``rig``; on exit stop and confirm every axis not yet confirmed stopped (``release_stop``),
    close, release the lock. Stopped by a signal or ``rig stop`` outside a plan, it stops every
    axis and switches the lamp off (``holder.stopped_safely``).
    ``sections(rig, speedup)``: the caller's context manager yielding (the rig its devices are
    connected by, the running simulation or None); None: the rig's own sections, real devices.
    ``goniofrost.rig.simulated.device_sections`` starts a simulated rig's devices for the command
    (at ``speedup``; its clock is the session clock): ``goniofrost sim --write-rig`` gives twins
    that outlive one command."""
    from contextlib import nullcontext

    from drivers.rig_devices import RigDevices
    from goniofrost.capture.holder import stopped_safely
    from goniofrost.rig.device_log import DeviceLog
    from goniofrost.rig.hardware import WallClock
    from goniofrost.rig.lock import rig_lock
    from goniofrost.rig.stop import release_stop

    opened = nullcontext((rig, None)) if sections is None else sections(rig, speedup)
    with rig_lock(rig, program) as lock, DeviceLog.capture(), opened as (resolved, simulation):
        devices = RigDevices.from_rig(resolved)
        devices.connect_all(enable=enable)
        try:
            clock = simulation.clock if simulation is not None else WallClock()
            hardware = ConsoleHardware(devices.axes, devices.lamp, clock, rig_lock=lock)
            with stopped_safely(hardware):  # rig stop's SIGTERM between plans: axes stopped, lamp off
                yield hardware
        finally:
            try:
                release_stop(devices.axes)
            finally:
                devices.close_all()


# ----- the dry run -------------------------------------------------------------------------------
# Real seconds a host takes to start a move and poll its arrival (10 ms polls; 30 to 80 ms seen at
# load 20 on 2 cores): on twins whose clock runs S times faster it is S times as much of theirs.
HOST_LATENCY_S = 0.05


def latency_allowance(speedup: float = 1.0) -> float:
    """Seconds (of the clock the moves are timed on) a move may differ from its plan by latency
    alone: 0.5 s, plus the host's latency on a faster clock (``speedup`` - 1 times HOST_LATENCY_S)."""
    return 0.5 + (float(speedup) - 1.0) * HOST_LATENCY_S


@dataclass(frozen=True)
class TimedMove:
    """One move of a dry run: plan ``index`` (None: homing), planned and measured seconds, and the
    ``allowance_s`` of latency it may carry (``latency_allowance``)."""

    index: int | None
    planned_s: float | None
    measured_s: float
    allowance_s: float = 0.5

    @property
    def differs(self) -> bool:
        """Measured more than 20 % and ``allowance_s`` away from the plan (polling and start-up
        latency stay within)."""
        if self.planned_s is None:
            return False
        gap = abs(self.measured_s - self.planned_s)
        return gap > self.allowance_s and gap > 0.2 * self.planned_s


def dry_run_plan(rig, plan_doc: dict):
    """Home, every sample's pose in capture order, home again: the plan's motion, no camera or lamp."""
    yield Home(tuple(rig.joint_names))
    for index, sample in enumerate(plan_doc["samples"]):  # plan index = position in capture order
        yield Move(index, tuple((name, float(sample["joints"][name])) for name in rig.joint_names))
    yield Home(tuple(rig.joint_names))


def dry_run(rig, plan_doc: dict, hardware, on_move=None) -> list[TimedMove]:
    """Run ``dry_run_plan`` on ``hardware`` through the engine core, timing each step on its clock;
    ``on_move(TimedMove)`` after each (progress). On failure, Ctrl-C or a stop request every axis
    is stopped and confirmed (``SessionFault`` / ``SessionInterrupted``). On the twins of a rig
    file of ``goniofrost sim --write-rig`` the wall clock's seconds are scaled to their clock's
    (``twins_speedup``), as the plan's times are."""
    from goniofrost.capture.plan_runner import PlanRunner

    planned = [float(s["move_s"]) for s in plan_doc["samples"]] + [float(plan_doc.get("return_home_s", 0.0))]
    scale = twins_speedup(rig)
    timed: list[TimedMove] = []

    def timing(plan):
        """The dry-run plan, timing each of its steps between yield and answer."""
        result = None
        while True:
            try:
                step = plan.send(result)
            except StopIteration:
                return timed
            t0 = hardware.clock.now()
            result = yield step
            k = len(timed)  # 0: the first homing (the plan's moves start at home), then the samples, then home
            move = TimedMove(getattr(step, "index", None), None if k == 0 else planned[k - 1],
                             (hardware.clock.now() - t0) * scale, latency_allowance(scale))
            timed.append(move)
            if on_move is not None:
                on_move(move)

    return PlanRunner(hardware, ".", program="capture --dry-run").execute_plan(timing(dry_run_plan(rig, plan_doc)))


def twins_speedup(rig) -> float:
    """How much faster than the wall clock a real rig file's devices run: its twins' clock speed-up
    (``rig.twins``, a rig file of ``goniofrost sim --write-rig``), else 1. A simulated rig's
    session clock is already the simulation's."""
    return 1.0 if rig.simulated else float((rig.twins or {}).get("clock_speedup", 1.0))


# ----- status ------------------------------------------------------------------------------
@dataclass(frozen=True)
class AxisReading:
    """One axis as read now: position as the axis reads it and aligned (physical = reading + the
    alignment's zero offset), limits, moving, enabled, alarm (None when healthy); degrees."""

    axis: str
    position_deg: float
    aligned_deg: float
    limits_deg: tuple[float, float]
    moving: bool
    enabled: bool
    alarm: str | None

    def as_dict(self) -> dict:
        out = dict(self.__dict__)
        out["limits_deg"] = list(self.limits_deg)
        return out


def read_status(rig, hardware) -> tuple[list[AxisReading], dict | None]:
    """Every axis's reading and the lamp's state ({"on", "photodiode"}; None without a lamp)."""
    offsets = rig.alignment.offsets_deg if rig.alignment is not None else {}
    readings = []
    for name, axis in hardware.axes.items():
        status = axis.status()
        readings.append(AxisReading(name, float(status.position_deg), float(status.position_deg) + offsets.get(name, 0.0),
                                    tuple(rig.axes[name].limits_deg), bool(status.moving), bool(status.enabled),
                                    status.fault))
    lamp = None
    if hardware.lamp is not None:
        lamp = {"on": bool(hardware.lamp.is_on()), "photodiode": float(hardware.lamp.photodiode())}
    return readings, lamp
