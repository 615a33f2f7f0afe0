"""Carry out a plan's device steps on a Hardware: the one place the capture calls devices.

``StepExecutor(hardware, folder)(step)`` executes one step (home, move, lamp, target, expose,
save the calibration arrays) and returns its result (see ``goniofrost.capture.steps``); its
``stop`` goes through the rig's one stop path (``goniofrost.rig.stop.stop_axes``), used by the
engine on any failure. The engine adds the journal on top; a camera bench (tests, benchmarks)
uses the executor alone.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from goniofrost.core.atomic_file import output_errors
from goniofrost.capture.steps import Expose, Frame, Home, LampOff, LampOn, Move, Reached, SaveCalibration, SetTarget
from goniofrost.rig.contract import Hardware
from goniofrost.rig.stop import AxisStop, stop_axes

log = logging.getLogger(__name__)
LAMP_OFF_ATTEMPTS = 2  # a reply lost once (a loaded host) must not leave the lamp reported on


@dataclass
class BenchHardware:
    """A Hardware of given devices: a camera and a lamp on an optical bench, no axes unless given
    (calibration tests and benchmarks run the calibration and sample plans on it)."""

    lamp: object
    camera: object
    clock: object
    simulated: bool = True
    axes: dict = field(default_factory=dict)
    simulation: object = None


class StepExecutor:
    """Execute device steps on ``hardware``; files go under ``folder`` (the session folder)."""

    def __init__(self, hardware: Hardware, folder) -> None:
        self.hw = hardware
        self.folder = Path(folder).resolve()  # journaled paths must survive a cd
        self.moving_to: dict[str, float | None] = {}  # axis -> target of a move started, not yet seen to end
        self._handlers = {Home: self.home, Move: self.move, LampOn: self.lamp_on, LampOff: self.lamp_off,
                          SetTarget: self.set_target, Expose: self.expose, SaveCalibration: self.save_calibration}

    def __call__(self, step):
        """Execute ``step``; steps without a device action (Phase, ...) return None."""
        handler = self._handlers.get(type(step))
        return None if handler is None else handler(step)

    def stop(self) -> list[AxisStop]:
        """Stop every axis through the one stop path (``stop_axes``); never raises."""
        stops = stop_axes(self.hw.axes, self.moving_to)
        for s in stops:
            if s.confirmed:
                self.moving_to.pop(s.axis, None)
        return stops

    def switch_lamp_off(self) -> str | None:
        """Switch the lamp off whatever happened before; never raises. Returns None when the lamp
        confirmed it, else why not."""
        error = None
        for _attempt in range(LAMP_OFF_ATTEMPTS):  # the lamp driver does not retry; switching off twice is harmless
            try:
                self.hw.lamp.off()
                return None
            except Exception as exc:  # noqa: BLE001 - on the way out of a failed session
                log.warning("switching the lamp off failed: %s", exc)
                error = str(exc) or type(exc).__name__
        return error

    # ----- a simulated rig's drills and state (nothing on a real rig) ---------------------------
    def arm_drills(self, sample_index: int) -> list[dict]:
        """Arm the fault drills due at plan sample ``sample_index``; return them."""
        sim = self.hw.simulation
        return [] if sim is None else sim.arm_faults(sample_index)

    def struck_drills(self) -> list[dict]:
        sim = self.hw.simulation
        return [] if sim is None else sim.struck_faults()

    def retire_drills(self, drills: list[dict]) -> None:
        if self.hw.simulation is not None and drills:
            self.hw.simulation.retire_faults(drills)

    def checkpoint(self) -> dict | None:
        """The simulated state to journal (None on a real rig)."""
        sim = self.hw.simulation
        return None if sim is None else sim.checkpoint()

    def restore(self, state: dict) -> None:
        if self.hw.simulation is not None:
            self.hw.simulation.restore(state)

    # ----- device steps -----------------------------------------------------------------------
    def home(self, step: Home) -> Reached:
        t0, utc0 = self.hw.clock.now(), time.time()
        statuses = self._start({name: (self.hw.axes[name].home, None) for name in step.axes})  # together
        self._wait(statuses)
        joints = {name: self.hw.axes[name].position() for name in step.axes}
        return Reached(joints, self.hw.clock.now() - t0, utc0)

    def move(self, step: Move) -> Reached:
        t0, utc0 = self.hw.clock.now(), time.time()
        statuses = self._start({name: (lambda axis=self.hw.axes[name], deg=deg: axis.move_to(deg), deg)
                                for name, deg in step.joints})  # all axes together
        joints = self._wait(statuses)
        seconds = self._profile_seconds(statuses, joints) if self.hw.simulated else self.hw.clock.now() - t0
        return Reached(joints, seconds, utc0)

    def _start(self, starts: dict) -> dict:
        """Start each axis's move ({axis: (callable -> MoveStatus, target degrees or None)}); each
        counts as under way from just before its command (a failed command may still have reached
        the device)."""
        statuses = {}
        for name, (start, target) in starts.items():
            self.moving_to[name] = target
            statuses[name] = start()
            self.moving_to[name] = float(statuses[name].target)
        return statuses

    def _wait(self, statuses: dict) -> dict:
        """Wait for each started move; return {axis: final degrees}."""
        joints = {}
        for name, status in statuses.items():
            joints[name] = float(status.wait())
            self.moving_to.pop(name, None)
        return joints

    def _profile_seconds(self, statuses, joints: dict) -> float:
        """Seconds of the slowest axis's trapezoidal move (what the simulated axes really take).

        Timing a simulated rig on its fast clock would add polling latency times the speed-up.
        """
        from drivers.axis import trapezoid_time

        times = []
        for status, (name, final) in zip(statuses.values(), joints.items()):
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
        with output_errors(path):
            path.parent.mkdir(parents=True, exist_ok=True)
        before, t0, wall0 = self.hw.lamp.photodiode(), self.hw.clock.now(), time.perf_counter()
        with output_errors(path):  # the camera writes the RAW file there: a full disk is one line
            written = self.hw.camera.capture(step.exposure_s, path)
        wall_s, clock_s = time.perf_counter() - wall0, self.hw.clock.now() - t0
        lamp = 0.5 * (before + self.hw.lamp.photodiode())
        # the exposure the camera reports it took (read back: a camera rounds), not the one asked for
        exposure_s = float(getattr(written, "exposure_s", step.exposure_s))
        # simulated: the exposure time the camera integrated (the clock would add rendering time)
        seconds = exposure_s if self.hw.simulated else clock_s
        return Frame(Path(written.path), exposure_s, read_raw(written.path), lamp, seconds, wall_s)

    def save_calibration(self, step: SaveCalibration):
        with output_errors(self.folder / step.folder):
            step.record.save(self.folder / step.folder)
        return step.record

    def read_conditions(self, suspenders, reference: float | None):
        """What ``suspenders`` (``goniofrost.rig.suspenders.Suspenders``) look at, read from the devices
        as a ``Reading`` (``reference``: the run's first photodiode reading); the first device that
        does not answer is named in ``silent``."""
        from drivers.errors import DeviceError
        from drivers.interlock import Interlock
        from goniofrost.rig.suspenders import Reading

        photodiode = closed = None
        name = "lamp"
        try:
            if suspenders.reads_lamp:
                photodiode = self.hw.lamp.photodiode()
            if suspenders.interlock:
                name = suspenders.interlock["device"]
                closed = Interlock(self.hw.axes[name], suspenders.interlock["input"]).is_closed()
        except DeviceError as exc:
            return Reading(photodiode, reference, silent=getattr(exc, "axis", None) or name)
        return Reading(photodiode, reference, None, closed)
