"""The capture engine: executes the session plan and owns every side effect.

``SessionEngine.run`` walks the steps of ``goniofrost.capture.steps.session_steps`` against a ``Hardware``
(axes, lamp, calibrator, clock), journals each sample in one transaction the moment it is
measured, appends it to samples.csv, shows a progress bar with the ETA, and

* on SIGINT or SIGTERM: stops every axis, records the event and raises ``SessionInterrupted``
  (the command exits 130); the journal stays resumable;
* on a device error: stops every axis, records the event and raises ``SessionFault`` with a
  clear one-line message (the command exits 2).

A journal commit is never torn by a signal: the signal is deferred until the commit is done.
"""
from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.capture.journal import Journal, SampleRecord, SamplesCsv
from goniofrost.capture.device_log import DeviceLog
from goniofrost.capture.steps import Calibrate, Commit, Home, LampOff, LampOn, Measure, Move, session_steps
from goniofrost.capture.signals import Deferral, SessionInterrupted, signals_raise

__all__ = ["SessionEngine", "SessionFault", "SessionInterrupted", "SessionStats", "Hardware"]

log = logging.getLogger(__name__)

RAW_DIR = "raw"
CALIBRATION_DIR = "calibration"


class SessionFault(GoniofrostError):
    """A device failed mid-session; every axis was stopped and the journal stays resumable."""


class Hardware(Protocol):
    """What the engine drives: ``axes`` (name -> drivers.axis.Axis), ``lamp`` (on/off/photodiode),
    ``calibrator`` (calib.Calibrator), ``clock`` (``now()`` in seconds: simulated on a simulated rig)."""

    axes: dict
    lamp: object
    calibrator: object
    clock: object


@dataclass
class SessionStats:
    """Times and counts of this run: motion and capture in session-clock seconds (simulated on a
    simulated rig), calibration and wall in real seconds."""

    motion_s: float = 0.0
    capture_s: float = 0.0
    calibration_s: float = 0.0
    captured: int = 0
    skipped: int = 0
    started_clock: float = 0.0
    ended_clock: float = 0.0
    wall_s: float = 0.0
    per_sample: list = field(default_factory=list)


@dataclass
class _Pending:
    """The sample between Move and Commit."""

    index: int
    joints: dict
    move_s: float
    started_utc: float
    measurement: object = None
    capture_s: float = 0.0


class SessionEngine:
    """Execute a session plan on ``hardware``, journaling into ``journal`` under ``session_dir``."""

    def __init__(self, inputs, hardware: Hardware, journal: Journal, session_dir, progress: bool = True) -> None:
        self.inputs, self.hw, self.journal = inputs, hardware, journal
        self.session_dir = Path(session_dir).resolve()  # journaled paths must survive a cd
        self.csv = SamplesCsv(self.session_dir / "samples.csv")
        self.progress = progress
        self.stats = SessionStats()
        self._pending: _Pending | None = None
        self._reached: dict = {}
        self._simulated = getattr(hardware, "simulation", None) is not None
        self._bar = None
        self._deferral, self._device_log = Deferral(), DeviceLog()  # replaced while running
        self._handlers = {Home: self._home, LampOn: self._lamp_on, LampOff: self._lamp_off,
                          Calibrate: self._calibrate, Move: self._move, Measure: self._measure,
                          Commit: self._commit}

    # ----- the run ------------------------------------------------------------------------
    def run(self) -> SessionStats:
        """Capture every sample not yet journaled; return the stats of this run."""
        done = self.journal.done_indices()
        (self.session_dir / RAW_DIR).mkdir(parents=True, exist_ok=True)
        self.csv.rewrite(self.journal.samples())  # the journal is the truth; no torn line survives
        self.stats.skipped = len(done)
        self.journal.add_event("session", f"started with {len(done)} of {len(self.inputs.samples)} samples done",
                               data={"done": sorted(done)})
        steps = session_steps(self.inputs.samples, self.inputs.rig.joint_names, done,
                              calibrated=self._restore_calibration(), white_joints=self.inputs.white_joints)
        wall0, self.stats.started_clock = time.monotonic(), self.hw.clock.now()
        with signals_raise() as deferral, self._progress(len(done)), DeviceLog.capture() as self._device_log:
            self._deferral = deferral
            try:
                self._execute_all(steps)
            finally:
                self._journal_device_log(quiet=True)
        self.stats.ended_clock, self.stats.wall_s = self.hw.clock.now(), time.monotonic() - wall0
        self.journal.add_event("session", "all samples captured",
                               data={"captured": self.stats.captured, "motion_s": self.stats.motion_s})
        return self.stats

    def _execute_all(self, steps) -> None:
        from drivers.errors import DeviceError

        step = None
        try:
            for step in steps:
                self._handlers[type(step)](step)
                self._journal_device_log()
        except DeviceError as exc:
            self._abort("fault", f"{exc}", getattr(exc, "axis", None), step)
            raise SessionFault(self._fault_message(exc, step)) from exc
        except GoniofrostError as exc:  # calibration or camera: this sample cannot be measured
            self._abort("error", f"{exc}", None, step)
            raise SessionFault(self._failure_message(exc, step)) from exc
        except SessionInterrupted:
            self._abort("interrupted", "SIGINT/SIGTERM: every axis stopped", None, step)
            raise
        except BaseException as exc:
            self._abort("error", f"{type(exc).__name__}: {exc}", None, step)
            raise

    def _abort(self, kind: str, message: str, axis, step) -> None:
        """Stop every axis first (safety), then record why; never raises, and a second Ctrl-C
        cannot cut the stopping short."""
        with self._deferral.ignored():
            problems = self.stop_all_axes()
            self._journal_device_log(quiet=True)  # the drivers' story first (retries, failed stops)
            data = {"step": repr(step), "stop_problems": problems}
            try:
                self.journal.add_event(kind, message, axis=axis, data=data)
            except Exception as exc:  # noqa: BLE001 - the original error matters more
                log.error("could not journal the %s event: %s", kind, exc)

    def _journal_device_log(self, quiet: bool = False) -> None:
        """Journal what the drivers logged (retries, failed stops, ...) since the last step.

        ``quiet``: on the way out of a failed session, never mask the original error.
        """
        try:
            for record in self._device_log.drain():
                self.journal.add_event("device", record.getMessage(),
                                       data={"logger": record.name, "level": record.levelname})
        except Exception as exc:  # noqa: BLE001 - only reached with quiet=True re-raising below
            if not quiet:
                raise
            log.error("could not journal the device log: %s", exc)

    def stop_all_axes(self) -> list[str]:
        """Command every axis to stop; return the problems met (each axis is tried)."""
        problems = []
        for name, axis in self.hw.axes.items():
            try:
                axis.stop()
            except Exception as exc:  # noqa: BLE001 - keep stopping the other axes
                problems.append(f"{name}: {exc}")
        return problems

    def _fault_message(self, exc, step) -> str:
        return f"device fault{self._where(step)}: {exc}. {self._safe_text()}"

    def _failure_message(self, exc, step) -> str:
        hint = ""
        if isinstance(step, Measure):
            s = self.inputs.samples[step.index]
            hint = f" (theta_i {s['theta_i_deg']:.1f} deg, theta_o {s['theta_o_deg']:.1f} deg)"
        return f"capture failed{self._where(step)}{hint}: {exc}. {_remedy(exc)}{self._safe_text()}"

    @staticmethod
    def _where(step) -> str:
        index = getattr(step, "index", None)
        return f" at plan sample {index}" if index is not None else f" during {type(step).__name__}"

    def _safe_text(self) -> str:
        n, done = len(self.inputs.samples), len(self.journal.done_indices())
        return (f"Every axis was stopped; {done} of {n} samples are safe in {self.journal.path}. "
                f"Fix the cause, then run the same command with --resume")

    # ----- step handlers -------------------------------------------------------------------
    def _home(self, step: Home) -> None:
        t0 = self.hw.clock.now()
        statuses = [self.hw.axes[name].home() for name in step.axes]  # axes home together
        for status in statuses:
            status.wait()
        self.stats.motion_s += self.hw.clock.now() - t0
        self.journal.add_event("home", f"homed {', '.join(step.axes)}",
                               data={n: self.hw.axes[n].position() for n in step.axes})

    def _lamp_on(self, _step: LampOn) -> None:
        self.hw.lamp.on()
        self.journal.add_event("lamp", "lamp on", data={"photodiode": self.hw.lamp.photodiode()})

    def _lamp_off(self, _step: LampOff) -> None:
        self.hw.lamp.off()
        self.journal.add_event("lamp", "lamp off")

    def _calibrate(self, _step: Calibrate) -> None:
        from planner.kinematics import forward

        t0 = time.monotonic()  # wall time: on a fast simulated clock, rendering would be multiplied
        white_pose = forward(self.inputs.rig, self._reached)  # the pose actually reached
        record = self.hw.calibrator.calibrate(self.session_dir / CALIBRATION_DIR, white_pose=white_pose)
        self.stats.calibration_s += time.monotonic() - t0
        self.journal.set_calibration(record.to_dict())
        self.journal.add_event("calibration", "dark, flat and white reference taken",
                               data={"scale": record.scale.tolist(), "white": record.white})

    def _restore_calibration(self) -> bool:
        """Reuse the journaled calibration (a resumed session); False if there is none or its
        arrays changed (then the session calibrates again)."""
        from calib import CalibrationError, CalibrationRecord

        stored = self.journal.calibration()
        if stored is None:
            return False
        try:
            record = CalibrationRecord.from_dict(stored)
        except CalibrationError as exc:
            self.journal.add_event("calibration", f"cannot reuse the journaled calibration ({exc}); calibrating again")
            return False
        if list(record.exposures_s) != list(self.hw.calibrator.ladder):  # the rig file's ladder changed
            self.journal.add_event("calibration", f"exposure ladder changed from {record.exposures_s} to "
                                   f"{self.hw.calibrator.ladder}; calibrating again")
            return False
        self.hw.calibrator.record = record
        return True

    def _move(self, step: Move) -> None:
        t0, utc0 = self.hw.clock.now(), time.time()
        statuses = [self.hw.axes[name].move_to(deg) for name, deg in step.joints]  # all axes together
        self._reached = {name: float(status.wait()) for (name, _), status in zip(step.joints, statuses)}
        seconds = self._profile_seconds(statuses) if self._simulated else self.hw.clock.now() - t0
        self.stats.motion_s += seconds
        if step.index is not None:
            self._pending = _Pending(step.index, self._reached, seconds, utc0)

    def _profile_seconds(self, statuses) -> float:
        """Seconds of the slowest axis's trapezoidal move (what the simulated axes really take).

        Timing a simulated rig on its fast clock would add polling latency times the speed-up.
        """
        from drivers.axis import trapezoid_time

        return max((trapezoid_time(s.final_deg - s.start, s.axis.config.speed_deg_s, s.axis.config.accel_deg_s2)
                    for s in statuses), default=0.0)

    def _measure(self, step: Measure) -> None:
        from planner.kinematics import forward

        pending = self._pending
        w_i, w_o = forward(self.inputs.rig, pending.joints)  # the pose actually reached
        t0 = self.hw.clock.now()
        pending.measurement = m = self.hw.calibrator.measure(w_i, w_o, self.session_dir / RAW_DIR, step.index)
        # simulated: the exposure time the camera integrated (the clock would add rendering time)
        pending.capture_s = float(sum(m.exposures_s)) if self._simulated else self.hw.clock.now() - t0
        self.stats.capture_s += pending.capture_s

    def _commit(self, step: Commit) -> None:
        record = self._record(self._pending)
        with self._deferral.critical():  # a signal waits until the sample is durable
            self.journal.commit_sample(record)
            self.csv.append(record)
        self._pending = None
        self.stats.captured += 1
        self.stats.per_sample.append({"index": record.plan_index, "snr": record.snr})
        if self._bar is not None:
            self._bar.update(1)

    def _record(self, pending: _Pending) -> SampleRecord:
        sample, m = self.inputs.samples[pending.index], pending.measurement
        return SampleRecord(
            plan_index=pending.index, cell=int(self.inputs.cells[pending.index]),
            theta_h_deg=float(sample["theta_h_deg"]), theta_d_deg=float(sample["theta_d_deg"]),
            phi_d_deg=float(sample["phi_d_deg"]), rgb=_triple(m.rgb), sigma=_triple(m.sigma),
            snr=float(np.min(m.snr)), joints=pending.joints, exposures_s=tuple(map(float, m.exposures_s)),
            frames_taken=int(m.frames_taken), frames_skipped=int(m.frames_skipped),
            raw_paths=tuple(str(p) for p in m.raw_paths), lamp_relative=float(m.lamp_relative),
            move_s=pending.move_s, capture_s=pending.capture_s, started_utc=pending.started_utc,
            committed_utc=time.time(), status=",".join(getattr(m, "flags", [])) or "ok")

    @contextmanager
    def _progress(self, initial: int):
        from tqdm import tqdm

        total = len(self.inputs.samples)
        with tqdm(total=total, initial=initial, unit="sample", desc="capture", file=sys.stderr,
                  disable=not self.progress, dynamic_ncols=True) as bar:
            self._bar = bar
            try:
                yield bar
            finally:
                self._bar = None


def _remedy(exc) -> str:
    """What an operator can do about a measurement that failed (empty if nothing specific)."""
    from calib.errors import MarkerError, SaturationError, UnderexposedError

    if isinstance(exc, MarkerError):
        return "If the camera cannot see the holder at this angle, plan again with --max-angle. "
    if isinstance(exc, SaturationError):
        return "Add shorter exposures to camera.exposures_s in the rig file (or dim the lamp). "
    if isinstance(exc, UnderexposedError):
        return "Add longer exposures to camera.exposures_s in the rig file. "
    return ""


def _triple(values) -> tuple[float, float, float]:
    a = np.asarray(values, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))
