"""The Hardware contract: what the capture engine may ask of a rig, and nothing more.

``Hardware`` bundles axes, a lamp, a camera and a clock (and, on a simulated rig, its
``Simulation``). The real and simulated rigs
(``goniofrost.rig.hardware.RigHardware`` over ``drivers``) satisfy it, and so do the small
fakes of the engine tests; the engine never reaches past these members.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping, Protocol, runtime_checkable


class MoveStatus(Protocol):
    """A started move (``drivers.axis.MoveStatus``): where it started and where to (degrees), and a
    wait for its end."""

    start: float
    target: float

    def wait(self) -> float:
        """Block until the move ends (bounded by the axis's own timeout); return the final degrees."""


class MotionProfile(Protocol):
    """An axis's trapezoid (``drivers.axis.AxisConfig``): deg/s and deg/s^2."""

    speed_deg_s: float
    accel_deg_s2: float


@runtime_checkable
class Axis(Protocol):
    """One rotation axis in degrees (``drivers.axis.Axis``)."""

    name: str
    config: MotionProfile

    @property
    def connected(self) -> bool: ...

    def move_to(self, deg: float) -> MoveStatus: ...

    def home(self) -> MoveStatus: ...

    def position(self) -> float: ...

    def stop(self) -> None:
        """Command a stop (decelerate) without waiting."""

    def confirm_stopped(self) -> float:
        """Wait (bounded) until the device reports the axis at rest; return where (degrees). Raises
        when the device cannot tell or still reports motion."""


@runtime_checkable
class Lamp(Protocol):
    """The lamp and its monitor photodiode (``drivers.lamp.Lamp``)."""

    def on(self) -> None: ...

    def off(self) -> None: ...

    def photodiode(self) -> float:
        """Intensity relative to nominal (1.0; 0 when off)."""


@runtime_checkable
class Camera(Protocol):
    """A camera writing one RAW file per exposure (``drivers.camera.Camera``)."""

    def set_target(self, target: str) -> None:
        """Put "sample", "white" or "flat" in front of the lens (a real rig asks the operator)."""

    def capture(self, exposure_s: float, path: Path):
        """Expose for ``exposure_s`` s; return a frame whose ``path`` is the RAW file written."""


@runtime_checkable
class Clock(Protocol):
    """The session clock (simulated seconds on a simulated rig)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of session time (a suspended run; simulated: real time / speed-up)."""


class Simulation(Protocol):
    """What the engine may ask of a simulated rig beyond its devices (``sim.rig.SimulatedRig``).

    Fault drills: ``arm_faults(sample_index)`` before each plan sample (the drills armed, each a
    dict with its ``drill`` number), ``struck_faults()`` (the armed drills that struck),
    ``retire_faults(drills)`` (drills that struck in an earlier run: never armed again).
    Reproducible resumes: ``checkpoint()`` (a JSON-safe state, journaled with each sample and the
    calibration) and ``restore(state)`` (before the first sample a resumed run captures).
    """

    def arm_faults(self, sample_index: int) -> list[dict]: ...

    def struck_faults(self) -> list[dict]: ...

    def retire_faults(self, drills: Iterable[dict]) -> None: ...

    def checkpoint(self) -> dict: ...

    def restore(self, state: dict) -> None: ...


@runtime_checkable
class Hardware(Protocol):
    """What a capture session drives. ``simulated``: time is accounted from the models (motion
    profiles, exposure times) rather than from a clock that also counts rendering and polling.
    ``simulation``: the simulated rig's drills and state (None on a real rig or a bench)."""

    axes: Mapping[str, Axis]
    lamp: Lamp
    camera: Camera
    clock: Clock
    simulated: bool
    simulation: Simulation | None
