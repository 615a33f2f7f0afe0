"""Carry out a plan's device steps on a Hardware, and stop every axis: the one place devices are called.

``StepExecutor(hardware, folder)(step)`` executes one step (home, move, lamp, target, expose,
save the calibration arrays) and returns its result (see ``goniofrost.capture.steps``);
``stop_axes`` is the one stop path for all axes, used by the engine on any failure and by the
hardware wiring on release. The engine adds the journal on top; a camera bench (tests,
benchmarks) uses the executor alone.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from goniofrost.capture.contract import Axis, Hardware
from goniofrost.capture.steps import Expose, Frame, Home, LampOff, LampOn, Move, Reached, SaveCalibration, SetTarget

log = logging.getLogger(__name__)


def stop_axes(axes: Mapping[str, Axis]) -> list[str]:
    """Command every connected axis to stop; never raise. Returns the problems met ("axis: error"),
    each also logged; every axis is tried whatever the others do."""
    problems = []
    for name, axis in axes.items():
        if not axis.connected:
            continue
        try:
            axis.stop()
        except Exception as exc:  # noqa: BLE001 - keep stopping the other axes
            log.warning("stop %s failed: %s", name, exc)
            problems.append(f"{name}: {exc}")
    return problems


@dataclass
class BenchHardware:
    """A Hardware of given devices: a camera and a lamp on an optical bench, no axes unless given
    (calibration tests and benchmarks run the calibration and sample plans on it)."""

    lamp: object
    camera: object
    clock: object
    simulated: bool = True
    axes: dict = field(default_factory=dict)


class StepExecutor:
    """Execute device steps on ``hardware``; files go under ``folder`` (the session folder)."""

    def __init__(self, hardware: Hardware, folder) -> None:
        self.hw = hardware
        self.folder = Path(folder).resolve()  # journaled paths must survive a cd
        self._handlers = {Home: self.home, Move: self.move, LampOn: self.lamp_on, LampOff: self.lamp_off,
                          SetTarget: self.set_target, Expose: self.expose, SaveCalibration: self.save_calibration}

    def __call__(self, step):
        """Execute ``step``; steps without a device action (Phase, ...) return None."""
        handler = self._handlers.get(type(step))
        return None if handler is None else handler(step)

    def home(self, step: Home) -> Reached:
        t0, utc0 = self.hw.clock.now(), time.time()
        statuses = [self.hw.axes[name].home() for name in step.axes]  # axes home together
        for status in statuses:
            status.wait()
        joints = {name: self.hw.axes[name].position() for name in step.axes}
        return Reached(joints, self.hw.clock.now() - t0, utc0)

    def move(self, step: Move) -> Reached:
        t0, utc0 = self.hw.clock.now(), time.time()
        statuses = [self.hw.axes[name].move_to(deg) for name, deg in step.joints]  # all axes together
        joints = {name: float(status.wait()) for (name, _), status in zip(step.joints, statuses)}
        seconds = self._profile_seconds(statuses, joints) if self.hw.simulated else self.hw.clock.now() - t0
        return Reached(joints, seconds, utc0)

    def _profile_seconds(self, statuses, joints: dict) -> float:
        """Seconds of the slowest axis's trapezoidal move (what the simulated axes really take).

        Timing a simulated rig on its fast clock would add polling latency times the speed-up.
        """
        from drivers.axis import trapezoid_time

        times = []
        for status, (name, final) in zip(statuses, joints.items()):
            profile = self.hw.axes[name].config
            times.append(trapezoid_time(final - status.start, profile.speed_deg_s, profile.accel_deg_s2))
        return max(times, default=0.0)

    def lamp_on(self, _step: LampOn) -> float:
        """Switch on; return the photodiode's reading just after."""
        self.hw.lamp.on()
        return self.hw.lamp.photodiode()

    def lamp_off(self, _step: LampOff) -> None:
        self.hw.lamp.off()

    def set_target(self, step: SetTarget) -> None:
        self.hw.camera.set_target(step.target)

    def expose(self, step: Expose) -> Frame:
        """Photodiode, exposure, photodiode; then decode the RAW file the camera wrote."""
        from drivers.rawfile import read_raw

        path = self.folder / step.file
        path.parent.mkdir(parents=True, exist_ok=True)
        before, t0, wall0 = self.hw.lamp.photodiode(), self.hw.clock.now(), time.perf_counter()
        written = self.hw.camera.capture(step.exposure_s, path)
        wall_s, clock_s = time.perf_counter() - wall0, self.hw.clock.now() - t0
        lamp = 0.5 * (before + self.hw.lamp.photodiode())
        # simulated: the exposure time the camera integrated (the clock would add rendering time)
        seconds = float(step.exposure_s) if self.hw.simulated else clock_s
        return Frame(Path(written.path), float(step.exposure_s), read_raw(written.path), lamp, seconds, wall_s)

    def save_calibration(self, step: SaveCalibration):
        step.record.save(self.folder / step.folder)
        return step.record
