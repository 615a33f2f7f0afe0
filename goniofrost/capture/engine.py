"""The capture engine: runs the session plan and owns every side effect.

``SessionEngine.run`` drives the steps of ``goniofrost.capture.session_steps`` on a ``Hardware``
(``goniofrost.capture.contract``) through a ``StepExecutor`` and journals each step as it
happens: a row in the journal's ``steps`` table when it starts and when it ends. On top of the
devices it commits each sample in one transaction the moment it is measured, appends it to
samples.csv, journals the calibration, lamp and homing events, times the parts of the session
and shows a progress bar with the ETA, and

* on SIGINT or SIGTERM: stops every axis, switches the lamp off, records the event and raises
  ``SessionInterrupted`` (the command exits 130); the journal stays resumable;
* on a device error (or a camera, calibration or output error): the same, and raises
  ``SessionFault`` with a one-line message (the command exits 2).

Every message says axis by axis what was confirmed at rest and what was not (an axis that did not
confirm its stop may still be moving towards its target), and whether the lamp confirmed it is
off; the journal has the same as ``stop`` and ``lamp`` events. On a simulated rig,
``goniofrost.capture.rehearsal`` arms the fault drills and makes a resumed run measure what one
run would have.

A journal write is never torn by a signal: the signal waits until the write is done.
"""
from __future__ import annotations

import dataclasses
import logging
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from goniofrost.core.atomic_file import reason_of
from goniofrost.core.errors import GoniofrostError, OutputError
from goniofrost.capture.contract import Hardware
from goniofrost.capture.device_log import DeviceLog
from goniofrost.capture.executor import StepExecutor, stop_text
from goniofrost.capture.journal import Journal, SamplesCsv
from goniofrost.capture.rehearsal import Rehearsal
from goniofrost.capture.session_steps import SessionSpec, session_steps
from goniofrost.capture.signals import Deferral, SessionInterrupted, signals_raise
from goniofrost.capture.steps import (Assess, Commit, Expose, Home, LampOff, LampOn, Move, Phase, SaveCalibration,
                                     step_detail)

__all__ = ["SessionEngine", "SessionFault", "SessionInterrupted", "SessionStats", "Hardware"]

log = logging.getLogger(__name__)


class SessionFault(GoniofrostError):
    """A device or a step failed mid-session; the axes were told to stop (the message says which
    confirmed it), the lamp to switch off, and the journal stays resumable."""


@dataclass
class SessionStats:
    """Times and counts of this run: motion and capture in session-clock seconds (simulated on a
    simulated rig), the parts of the session (``phase_s``: "calibration", "samples") and the
    whole run in real seconds."""

    motion_s: float = 0.0
    capture_s: float = 0.0
    captured: int = 0
    skipped: int = 0
    started_clock: float = 0.0
    ended_clock: float = 0.0
    wall_s: float = 0.0
    phase_s: dict = field(default_factory=dict)
    per_sample: list = field(default_factory=list)
    batches: list = field(default_factory=list)

    @property
    def calibration_s(self) -> float:
        """Real seconds spent calibrating in this run."""
        return self.phase_s.get("calibration", 0.0)


class SessionEngine:
    """Execute the session plan of ``spec`` (a SessionSpec, e.g. ``SessionSpec.from_inputs``) on
    ``hardware``, journaling into ``journal`` under ``session_dir``."""

    def __init__(self, spec: SessionSpec, hardware: Hardware, journal: Journal, session_dir,
                 progress: bool = True, device_log: DeviceLog | None = None) -> None:
        self.spec, self.hw, self.journal = spec, hardware, journal
        self.devices = StepExecutor(hardware, session_dir)
        self.session_dir = self.devices.folder
        self.csv = SamplesCsv(self.session_dir / "samples.csv", spec.batch_ends if spec.target is not None else ())
        self.progress = progress
        self.stats = SessionStats()
        self._run = 0
        self._row: int | None = None       # journal row of the step being executed
        self._phase: tuple | None = None   # (name, monotonic start) of the part under way
        self._bar = None
        self._given_log = device_log  # the runner's, covering connect and release too; else our own
        self._deferral, self._device_log = Deferral(), DeviceLog()  # replaced while running
        self._stopped: tuple = ([], None)  # (AxisStop list, lamp error) of the abort, if any
        self.rehearsal = Rehearsal(self.devices, journal)  # a simulated rig's drills and state
        self._journal_result = {Home: self._homed, LampOn: self._lamp_on, LampOff: self._lamp_off,
                                Move: self._moved, Expose: _exposed, Phase: self._phase_started,
                                SaveCalibration: self._calibration_saved, Assess: self._assessed,
                                Commit: self._commit}

    # ----- the run ------------------------------------------------------------------------
    def run(self) -> SessionStats:
        """Capture every sample not yet journaled; return the stats of this run."""
        done = self.journal.done_indices()
        records = self.journal.samples()
        self.csv.rewrite(records)  # the journal is the truth; no torn line survives
        self.stats.skipped = len(done)
        self._run = self.journal.next_run()
        self.journal.add_event("session", f"started with {len(done)} of {len(self.spec.samples)} samples done",
                               data={"done": sorted(done), "run": self._run})
        calibration = self._restore_calibration()
        self.rehearsal.prepare(len(self.spec.samples), done, calibration is not None)
        plan = session_steps(self.spec, done, calibration=calibration,
                             measured={r.plan_index: r.rgb for r in records}, records=records)
        wall0, self.stats.started_clock = time.monotonic(), self.hw.clock.now()
        with signals_raise() as deferral, self._progress(len(done)), self._device_log_scope():
            self._deferral = deferral
            try:
                self._drive(plan)
            finally:
                self._end_phase()
                self._journal_device_log(quiet=True)
        self.stats.ended_clock, self.stats.wall_s = self.hw.clock.now(), time.monotonic() - wall0
        last = self.stats.batches[-1] if self.stats.batches else None
        message = ("all samples captured" if last is None or last["decision"] == "plan used up" else
                   f"capture stopped after {last['samples']} of {len(self.spec.samples)} samples: target reached")
        self.journal.add_event("session", message, data={"captured": self.stats.captured,
                                                         "motion_s": self.stats.motion_s})
        return self.stats

    def _drive(self, plan) -> None:
        """Execute each step and send its result back into the plan; on any failure stop every
        axis, switch the lamp off and journal why. An error the plan raises is charged to the step
        before it."""
        from drivers.errors import DeviceError

        step = result = None
        try:
            while True:
                try:
                    step = plan.send(result)
                except StopIteration:
                    return
                result = self._execute(step)
        except DeviceError as exc:
            message = self._abort("fault", f"{exc}", getattr(exc, "axis", None), step,
                                  lambda: self._fault_message(exc, step))
            raise SessionFault(message) from exc
        except GoniofrostError as exc:  # calibration, camera or an output path: this sample cannot be measured
            message = self._abort("error", f"{exc}", None, step, lambda: self._failure_message(exc, step))
            raise SessionFault(message) from exc
        except SessionInterrupted as exc:
            message = self._abort("interrupted", f"{exc or 'SIGINT/SIGTERM'}: session stopped", None, step,
                                  lambda: f"interrupted by {exc or 'a signal'}{self._where(step)}. "
                                          f"{self._safe_text('Run the same command with --resume to continue')}")
            raise SessionInterrupted(message) from exc
        except OSError as exc:  # a file the session writes (frames, samples.csv): one line, not a traceback
            where = exc.filename or self.session_dir
            error = OutputError(where, reason_of(exc, where))
            message = self._abort("error", f"{error}", None, step, lambda: self._failure_message(error, step))
            raise SessionFault(message) from exc
        except BaseException as exc:
            self._abort("error", f"{type(exc).__name__}: {exc}", None, step)
            raise
        finally:
            plan.close()

    def _execute(self, step):
        """Journal the step as running, execute it, journal how it ended; return its result."""
        if isinstance(step, Move) and step.index is not None:
            self.rehearsal.before_sample(step.index)
        with self._deferral.critical():
            self._row = self.journal.start_step(self._run, type(step).__name__, getattr(step, "index", None),
                                                step_detail(step))
        result = self.devices(step)
        journal_result = self._journal_result.get(type(step))
        with self._deferral.critical():  # a signal waits until the step's journaling is done
            summary = journal_result(step, result) if journal_result else {}
            self.journal.end_step(self._row, "done", summary)
            self._row = None
            self.rehearsal.journal_struck()
        self._journal_device_log()
        return result

    def _abort(self, kind: str, message: str, axis, step, operator_message=None) -> str:
        """Stop every axis first (safety), switch the lamp off, then record why and how each axis
        took the stop; never raises, and a second Ctrl-C cannot cut it short.

        ``operator_message()`` (called once every axis was told to stop: it says how they took it)
        gives the terminal's text, what went wrong and what to do next; it is journaled with the
        event, so that the monitor page shows the same words, and returned.
        """
        with self._deferral.ignored():
            stops = self.devices.stop()
            lamp_error = self.devices.switch_lamp_off()
            self._stopped = (stops, lamp_error)
            self._journal_device_log(quiet=True)  # the drivers' story first (retries, failed stops)
            text, failed = "", None
            try:
                text = operator_message() if operator_message else ""
            except Exception as exc:  # noqa: BLE001 - journal the stop first, then let it surface
                failed = exc
            data = {"step": repr(step), "plan_index": getattr(step, "index", None),
                    "stops": [dataclasses.asdict(s) for s in stops],
                    "stop_problems": [s.text() for s in stops if not s.confirmed], "lamp_off": lamp_error is None,
                    "operator_message": text}
            try:
                if self._row is not None:
                    self.journal.end_step(self._row, "interrupted" if kind == "interrupted" else "failed",
                                          {"error": message})
                self.rehearsal.journal_struck()
                self.journal.add_event(kind, message, axis=axis, data=data)
                self.journal.add_event("stop", stop_text(stops), data={"stops": data["stops"]})
                self.journal.add_event("lamp", "lamp off" if lamp_error is None else
                                       f"the lamp did not confirm it is off ({lamp_error})",
                                       data={"off": lamp_error is None, "error": lamp_error})
            except Exception as exc:  # noqa: BLE001 - the original error matters more
                log.error("could not journal the %s event: %s", kind, exc)
        if failed is not None:
            raise failed
        return text

    def _journal_device_log(self, quiet: bool = False) -> None:
        """Journal what the drivers logged (retries, failed stops, ...) since the last step.

        ``quiet``: on the way out of a failed session, never mask the original error.
        """
        try:
            self._device_log.journal_into(self.journal)
        except Exception as exc:  # noqa: BLE001 - only reached with quiet=True re-raising below
            if not quiet:
                raise
            log.error("could not journal the device log: %s", exc)

    @contextmanager
    def _device_log_scope(self):
        """The device log of the run: the one given (the runner's), else one of our own."""
        if self._given_log is not None:
            self._device_log = self._given_log
            yield
        else:
            with DeviceLog.capture() as self._device_log:
                yield

    def _fault_message(self, exc, step) -> str:
        return f"device fault{self._where(step)}: {exc}. {self._safe_text()}"

    def _failure_message(self, exc, step) -> str:
        hint, index = "", getattr(step, "index", None)
        if index is not None:
            s = self.spec.samples[index]
            hint = f" (theta_i {s['theta_i_deg']:.1f} deg, theta_o {s['theta_o_deg']:.1f} deg)"
        return f"capture failed{self._where(step)}{hint}: {exc}. {_remedy(exc)}{self._safe_text()}"

    def _where(self, step) -> str:
        index = getattr(step, "index", None)
        if index is not None:
            return f" at plan sample {index}"
        part = f" in the {self._phase[0]}" if self._phase else ""
        return f" during {type(step).__name__}{part}" if step is not None else " before the first step"

    def _safe_text(self, next_step: str = "Fix the cause, then run the same command with --resume") -> str:
        """What the abort did to the axes and the lamp, what is safe, and what to type next."""
        n = len(self.spec.samples)
        try:
            done = f"{len(self.journal.done_indices())} of {n}"
        except Exception:  # noqa: BLE001 - an unreadable journal must not hide the stop report
            done = "the committed"
        stops, lamp_error = self._stopped
        text = stop_text(stops)
        lamp = "the lamp is off" if lamp_error is None else "the lamp did not confirm it is off: it may still be on"
        check = " Check the axes named above before anything else moves." if any(not s.confirmed for s in stops) else ""
        return (f"{text[0].upper()}{text[1:]}; {lamp}.{check} {done} samples are safe in {self.journal.path}. "
                f"{next_step}")

    def _restore_calibration(self):
        """The journaled calibration to keep (a resumed session); None if there is none or its
        arrays or the exposure ladder changed (then the session calibrates again)."""
        from calib import CalibrationError, CalibrationRecord

        stored = self.journal.calibration()
        if stored is None:
            return None
        try:
            record = CalibrationRecord.from_dict(stored)
        except CalibrationError as exc:
            self.journal.add_event("calibration", f"cannot reuse the journaled calibration ({exc}); calibrating again")
            return None
        ladder = self.spec.camera["exposures_s"]
        if list(record.exposures_s) != list(ladder):  # the rig file's ladder changed
            self.journal.add_event("calibration", f"exposure ladder changed from {record.exposures_s} to "
                                   f"{ladder}; calibrating again")
            return None
        return record

    # ----- what each step adds to the journal and the stats (returns the step's result summary) -----
    def _homed(self, step: Home, reached) -> dict:
        self.stats.motion_s += reached.seconds
        self.journal.add_event("home", f"homed {', '.join(step.axes)}", data=reached.joints)
        return {"joints": reached.joints, "seconds": reached.seconds}

    def _lamp_on(self, _step: LampOn, photodiode: float) -> dict:
        self.journal.add_event("lamp", "lamp on", data={"photodiode": photodiode})
        return {"photodiode": photodiode}

    def _lamp_off(self, _step: LampOff, _result) -> dict:
        self.journal.add_event("lamp", "lamp off")
        return {}

    def _moved(self, _step: Move, reached) -> dict:
        self.stats.motion_s += reached.seconds
        return {"joints": reached.joints, "seconds": reached.seconds}

    def _phase_started(self, step: Phase, _result) -> dict:
        self._end_phase()
        self._phase = (step.name, time.monotonic())
        self.journal.add_event(step.name, PHASE_MESSAGES.get(step.name, f"{step.name} started"))
        return {}

    def _end_phase(self) -> None:
        if self._phase is not None:
            name, t0 = self._phase
            self.stats.phase_s[name] = self.stats.phase_s.get(name, 0.0) + time.monotonic() - t0
            self._phase = None

    def _calibration_saved(self, _step: SaveCalibration, record) -> dict:
        summary = self.rehearsal.with_state({"arrays": str(record.path), "sha256": record.sha256})
        self.journal.set_calibration(record.to_dict(), step=(self._row, summary))  # kept together with its state
        self.journal.add_event("calibration", "dark, flat and white reference taken",
                               data={"scale": record.scale.tolist(), "white": record.white})
        return summary

    def _assessed(self, step: Assess, _result) -> dict:
        summary = dataclasses.asdict(step)
        self.stats.batches.append(summary)
        self.journal.add_event("batch", f"batch {step.batch + 1}: {step.samples} samples, predicted error "
                               f"{step.predicted_error:.4g} (target {step.target:g}): {step.decision}", data=summary)
        return summary

    def _commit(self, step: Commit, _result) -> dict:
        record = dataclasses.replace(step.record, committed_utc=time.time())
        summary = self.rehearsal.with_state({"snr": record.snr, "status": record.status})
        # one durable transaction with its step and state (within _execute's critical section)
        self.journal.commit_sample(record, step=(self._row, summary))
        self.csv.append(record)
        self.stats.captured += 1
        self.stats.capture_s += record.capture_s
        self.stats.per_sample.append({"index": record.plan_index, "snr": record.snr})
        if self._bar is not None:
            self._bar.update(1)
        return summary

    @contextmanager
    def _progress(self, initial: int):
        from tqdm import tqdm

        from goniofrost.core.progress import show_progress

        total = len(self.spec.samples)
        with tqdm(total=total, initial=initial, unit="sample", desc="capture", file=sys.stderr,
                  disable=not show_progress(self.progress), dynamic_ncols=True) as bar:
            self._bar = bar
            try:
                yield bar
            finally:
                self._bar = None


PHASE_MESSAGES = {"calibration": "calibration started: dark frames, flat field, white reference",
                  "samples": "sample capture started"}


def _exposed(_step: Expose, frame) -> dict:
    return {"path": str(frame.path), "lamp_relative": frame.lamp_relative, "seconds": frame.seconds}


def _remedy(exc) -> str:
    """What an operator can do about a measurement that failed (empty if nothing specific)."""
    from calib.errors import MarkerError, MisalignedError, PatchTooSmallError, SaturationError, UnderexposedError

    if isinstance(exc, MisalignedError):
        return ("Run goniofrost align on this rig and capture with --alignment (or fix the camera model in "
                "the rig file). ")
    if isinstance(exc, PatchTooSmallError):
        return "The rig file's camera model differs from the camera: check camera.intrinsics and camera.mount. "
    if isinstance(exc, MarkerError):
        return "Check that the right holder card is mounted and lit. "
    if isinstance(exc, SaturationError):
        return "Add shorter exposures to camera.exposures_s in the rig file (or dim the lamp). "
    if isinstance(exc, UnderexposedError):
        return "Add longer exposures to camera.exposures_s in the rig file. "
    return ""
