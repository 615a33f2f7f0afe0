"""The engine core: run a plan of steps on a Hardware and own every side effect of it.

Every program that moves the rig (``capture``, ``align``, the console's hand commands) runs its
plan (a generator of the steps of ``goniofrost.capture.steps``, sent each step's result) through
a ``PlanRunner``:

* each step is executed by the one ``StepExecutor`` and, when a journal is given, journaled as a
  ``steps`` row when it starts and when it ends (a short hand command may run without a journal);
* the run is a ``RunStart`` and a ``RunEnd`` (``goniofrost.capture.records``) in the journal;
* SIGINT, SIGTERM and a stop request of the rig lock (``goniofrost.rig.lock``, checked
  between steps too) end the run ``STOPPED_BY_OPERATOR`` and raise ``SessionInterrupted``; a
  device error ends it ``FAULT``, a measurement or output error ``REFUSED``, each raising
  ``SessionFault`` with a one-line message. On every one of them every axis is stopped and
  confirmed through the one stop path (``goniofrost.rig.stop.stop_axes``), the lamp is switched off, and the
  message and the journal say axis by axis what was confirmed;
* the drivers' log goes to the journal (``DeviceLog``), off the terminal.

A journal write is never torn by a signal: the signal waits until the write is done. Subclasses
(``goniofrost.capture.engine.SessionEngine``, ``goniofrost.capture.align.AlignRunner``) add what
their steps journal, their words and how a completed run ends.
"""
from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import Any, Callable

from goniofrost.core.atomic_file import reason_of
from goniofrost.core.errors import GoniofrostError, OutputError
from goniofrost.rig.device_log import DeviceLog
from goniofrost.capture.executor import StepExecutor
from goniofrost.rig.stop import stop_text
from goniofrost.capture.records import EventKind, RunEnd, RunStart, RunStatus
from goniofrost.capture.signals import Deferral, RunStopped, SessionInterrupted, signals_raise
from goniofrost.capture.steps import step_detail

__all__ = ["PlanRunner", "SessionFault", "SessionInterrupted"]

log = logging.getLogger(__name__)


class SessionFault(GoniofrostError):
    """A device or a step failed mid-run; the axes were told to stop (the message says which
    confirmed it), the lamp to switch off, and the journal stays resumable."""


@dataclass(frozen=True)
class StepDone:
    """What the runner emits to its subscribers once a step is done and journaled: the ``step``,
    its ``result`` and the ``summary`` the journal holds of it."""

    step: Any
    result: Any
    summary: dict


class SubscriberWarning(RuntimeWarning):
    """A subscriber failed on a record: the run goes on (a display must never stop a measurement)."""


class PlanRunner:
    """Run plans on ``hardware`` (a ``goniofrost.rig.contract.Hardware``); files go under
    ``folder``. ``journal``: a ``Journal`` or None (no journal: the run's records stay in
    ``run_start``/``run_end`` only); ``device_log``: the caller's (covering connect and release
    too), else the runner captures its own; ``program``: the name its runs are journaled under."""

    program = "run"

    def __init__(self, hardware, folder, *, journal=None, device_log: DeviceLog | None = None,
                 program: str | None = None) -> None:
        self.hw, self.journal = hardware, journal
        self.devices = StepExecutor(hardware, folder)
        self.folder = self.devices.folder
        self.program = program or type(self).program
        self.run_start: RunStart | None = None
        self.run_end: RunEnd | None = None
        self._row: int | None = None       # journal row of the step being executed
        self._given_log = device_log
        self._deferral, self._device_log = Deferral(), DeviceLog()  # replaced while running
        self._stopped: tuple = ([], None)  # (AxisStop list, lamp error) of the abort, if any
        self.step_journal: dict = {}       # step type -> f(step, result) -> the step's result summary
        self._subscribers: list = []       # (callback, required): see subscribe

    def subscribe(self, callback: Callable[[StepDone], None], required: bool = False) -> None:
        """Hand every StepDone to ``callback``. A required one (a file the session keeps, as
        samples.csv) runs with the step's journaling, where no signal cuts in, and its error stops
        the run as the journal's does; another one's error is a SubscriberWarning and the run goes on."""
        self._subscribers.append((callback, required))

    # ----- what a subclass says (defaults: a plan without samples) ---------------------------
    def samples_planned(self) -> int:
        return 0

    def samples_captured(self) -> int:
        return 0

    def batches(self) -> int:
        return 0

    def completed(self, value) -> tuple[RunStatus, str]:
        """(status, reason) of a run whose plan returned ``value``."""
        return RunStatus.FINISHED, f"{self.program} finished"

    def before_step(self, step) -> None:
        """Called before each step is journaled (a simulated rig's drills)."""

    def after_journal(self) -> None:
        """Called inside each step's journaling (a simulated rig's struck drills)."""

    def run_scope(self):
        """A context around the whole run (a progress bar)."""
        return nullcontext()

    def leaving(self) -> None:
        """Called once the plan ended, however (the time of the part under way)."""

    def where(self, step) -> str:
        """' at plan sample N' / ' during Move' for the messages."""
        index = getattr(step, "index", None)
        if index is not None:
            return f" at plan sample {index}"
        return f" during {type(step).__name__}" if step is not None else " before the first step"

    def failure_hint(self, step) -> str:
        return ""

    def saved_text(self) -> str:
        """What is safe, for the messages after a stop."""
        return f"The run is journaled in {self.journal.path}" if self.journal is not None else "Nothing was journaled"

    def resume_text(self) -> str:
        """What to do after a fault or a refusal."""
        return "Fix the cause, then run the same command again"

    def continue_text(self) -> str:
        """What to do after an operator's stop: an option, not an instruction (a stopped move was
        stopped on purpose; running it again would start it again)."""
        return "To carry on from here, run the same command again"

    # ----- the run ------------------------------------------------------------------------
    def execute_plan(self, plan):
        """Run ``plan`` to its end; return what it returns (see module doc for how it may end)."""
        done = self.samples_captured()
        if self.journal is not None:
            self.run_start = self.journal.start_run(self.program, self.samples_planned(), done)
        else:
            self.run_start = RunStart(0, self.program, time.time(), self.samples_planned(), done)
        self.journal_event(EventKind.SESSION, f"{self.program} run {self.run_start.run} started with {done} of "
                           f"{self.samples_planned()} samples done", data={"run": self.run_start.run})
        with signals_raise() as deferral, self.run_scope(), self._device_log_scope():
            self._deferral = deferral
            try:
                value = self._drive(plan)
            finally:
                self.leaving()
                self._journal_device_log(quiet=True)
        status, reason = self.completed(value)
        self._end_run(status, reason)
        self.journal_event(EventKind.SESSION, reason, data={"status": status.value})
        return value

    def journal_event(self, kind: EventKind, message: str, axis=None, data=None) -> None:
        if self.journal is not None:
            self.journal.add_event(kind, message, axis=axis, data=data)

    def _end_run(self, status: RunStatus, reason: str, **stopped) -> None:
        self.run_end = RunEnd(self.run_start.run, status, reason, self.samples_planned(), self.samples_captured(),
                              self.batches(), self.run_start.started_utc, time.time(), **stopped)
        if self.journal is not None:
            self.journal.end_run(self.run_end)

    def _drive(self, plan):
        """Execute each step and send its result back into the plan; on any failure stop every
        axis, switch the lamp off and journal why. An error the plan raises is charged to the step
        before it."""
        from drivers.errors import DeviceError

        step = result = None
        try:
            while True:
                self._check_stop_request()
                try:
                    step = plan.send(result)
                except StopIteration as end:
                    return end.value
                self._safe_point(step)
                result = self._execute(step)
        except DeviceError as exc:
            message = self._abort(EventKind.FAULT, RunStatus.FAULT, f"{exc}", getattr(exc, "axis", None), step,
                                  lambda: f"device fault{self.where(step)}: {exc}. {_remedy(exc)}{self.safe_text()}")
            raise SessionFault(message) from exc
        except GoniofrostError as exc:  # calibration, camera or an output path: the run cannot go on
            message = self._abort(EventKind.ERROR, RunStatus.REFUSED, f"{exc}", None, step,
                                  lambda: self._failure_message(exc, step))
            raise SessionFault(message) from exc
        except SessionInterrupted as exc:
            who = self._stop_request() or str(exc) or "a signal"  # SIGTERM of a stop request names who asked
            message = self._abort(EventKind.INTERRUPTED, RunStatus.STOPPED_BY_OPERATOR, f"{who}: run stopped", None,
                                  step, lambda: f"interrupted by {who}{self.where(step)}. "
                                                f"{self.safe_text(self.continue_text())}")
            raise RunStopped(message) from exc
        except OSError as exc:  # a file the run writes (frames, samples.csv): one line, not a traceback
            where = exc.filename or self.folder
            error = OutputError(where, reason_of(exc, where))
            message = self._abort(EventKind.ERROR, RunStatus.REFUSED, f"{error}", None, step,
                                  lambda: self._failure_message(error, step))
            raise SessionFault(message) from exc
        except BaseException as exc:
            self._abort(EventKind.ERROR, RunStatus.FAULT, f"{type(exc).__name__}: {exc}", None, step)
            raise
        finally:
            plan.close()

    def at_safe_point(self, step) -> bool:
        """Whether the run may pause before ``step`` (default: before any step of a short plan)."""
        return True

    def _safe_point(self, step) -> None:
        """Ask the hardware's pause gate (a server's ``pause_gate(where)``, if any) whether the run
        may continue, at a safe point only: it blocks while the run is paused and raises
        SessionInterrupted when the run is stopped meanwhile."""
        gate = getattr(self.hw, "pause_gate", None)
        if gate is not None and self.at_safe_point(step):
            gate(self.where(step))

    def _stop_request(self) -> str | None:
        lock = getattr(self.hw, "rig_lock", None)
        return lock.stop_request() if lock is not None else None

    def _check_stop_request(self) -> None:
        """A stop request of the rig lock, between steps (its SIGTERM interrupts a step itself)."""
        request = self._stop_request()
        if request is not None:
            raise SessionInterrupted(request)

    def _execute(self, step):
        """Journal the step as running, execute it, journal how it ended; return its result."""
        self.before_step(step)
        if self.journal is not None:
            with self._deferral.critical():
                self._row = self.journal.start_step(self.run_start.run, type(step).__name__,
                                                    getattr(step, "index", None), step_detail(step))
        result = self.devices(step)
        journal_result = self.step_journal.get(type(step))
        with self._deferral.critical():  # a signal waits until the step's journaling is done
            summary = journal_result(step, result) if journal_result else {}
            if self.journal is not None:
                self.journal.end_step(self._row, "done", summary)
            self._row = None
            self.after_journal()
            done = StepDone(step, result, summary)
            for callback in (c for c, required in self._subscribers if required):
                callback(done)
        self._journal_device_log()
        self._emit(done)
        return result

    def _emit(self, done: StepDone) -> None:
        """Hand ``done`` to each subscriber that is not required; an error is a warning."""
        for callback in (c for c, required in self._subscribers if not required):
            try:
                callback(done)
            except Exception as exc:  # noqa: BLE001 - bluesky's rule: a subscriber never stops the run
                log.warning("subscriber %s failed on %s: %s", getattr(callback, "__qualname__", callback),
                            type(done.step).__name__, exc)
                warnings.warn(f"{type(done.step).__name__}: a subscriber failed: {exc}", SubscriberWarning,
                              stacklevel=2)

    def _abort(self, kind: EventKind, status: RunStatus, detail: str, axis, step, operator_message=None) -> str:
        """Stop every axis first (safety), switch the lamp off, then record why and how each axis
        took the stop (events and the RunEnd); never raises, and a second Ctrl-C cannot cut it short.

        ``operator_message()`` (called once every axis was told to stop: it says how they took it)
        gives the terminal's text, what went wrong and what to do next; it is journaled as the
        RunEnd's reason, so that the monitor page shows the same words, and returned.
        """
        with self._deferral.ignored():
            stops = self.devices.stop()
            lamp_error = self.devices.switch_lamp_off()
            self._stopped = (stops, lamp_error)
            self._journal_device_log(quiet=True)  # the drivers' story first (retries, failed stops)
            text, failed = "", None
            try:
                text = operator_message() if operator_message else detail
            except Exception as exc:  # noqa: BLE001 - journal the stop first, then let it surface
                failed, text = exc, detail
            index = getattr(step, "index", None)
            data = {"step": repr(step), "plan_index": index, "stops": [dataclasses.asdict(s) for s in stops],
                    "lamp_off": lamp_error is None}
            try:
                if self.journal is not None and self._row is not None:
                    self.journal.end_step(self._row, "interrupted" if kind is EventKind.INTERRUPTED else "failed",
                                          {"error": detail})
                self.after_journal()
                self.journal_event(kind, detail, axis=axis, data=data)
                self.journal_event(EventKind.STOP, stop_text(stops), data={"stops": data["stops"]})
                self.journal_event(EventKind.LAMP, "lamp off" if lamp_error is None else
                                   f"the lamp did not confirm it is off ({lamp_error})",
                                   data={"off": lamp_error is None, "error": lamp_error})
                self._end_run(status, text, detail=detail, axis=axis, plan_index=index, stops=tuple(stops),
                              lamp_off=lamp_error is None)
            except Exception as exc:  # noqa: BLE001 - the original error matters more
                log.error("could not journal the %s event: %s", kind, exc)
        if failed is not None:
            raise failed
        return text

    def _failure_message(self, exc, step) -> str:
        where = f"{self.where(step)}{self.failure_hint(step)}"
        return f"{self.program} failed{where}: {exc}. {_remedy(exc)}{self.safe_text()}"

    def safe_text(self, next_step: str | None = None) -> str:
        """What the abort did to the axes and the lamp, what is safe, and what to type next."""
        stops, lamp_error = self._stopped
        text = stop_text(stops)
        lamp = "the lamp is off" if lamp_error is None else "the lamp did not confirm it is off: it may still be on"
        check = " Check the axes named above before anything else moves." if any(not s.confirmed for s in stops) else ""
        return f"{text[0].upper()}{text[1:]}; {lamp}.{check} {self.saved_text()}. {next_step or self.resume_text()}"

    def _journal_device_log(self, quiet: bool = False) -> None:
        """Journal what the drivers logged (retries, failed stops, ...) since the last step.

        ``quiet``: on the way out of a failed run, never mask the original error.
        """
        if self.journal is None:
            return
        try:
            self.journal.add_device_log(self._device_log)
        except Exception as exc:  # noqa: BLE001 - only reached with quiet=True re-raising below
            if not quiet:
                raise
            log.error("could not journal the device log: %s", exc)

    @contextmanager
    def _device_log_scope(self):
        """The device log of the run: the one given (the caller's), else one of our own."""
        if self._given_log is not None:
            self._device_log = self._given_log
            yield
        else:
            with DeviceLog.capture() as self._device_log:
                yield


def _remedy(exc) -> str:
    """What an operator can do about a measurement that failed (empty if nothing specific)."""
    from calib.errors import MarkerError, MisalignedError, PatchTooSmallError, SaturationError, UnderexposedError
    from drivers.errors import NotHomedError

    if isinstance(exc, NotHomedError):
        # a simulated rig file starts fresh devices for every command: a home does not outlive it
        return (f"Home {exc.axis} first (goniofrost rig home; on a simulated rig file every command starts its "
                "devices afresh: rehearse with the twins of goniofrost sim --write-rig). ")
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
