"""The engine core: run a plan of steps on a Hardware and own every side effect of it.

Every program that moves the rig (``capture``, ``align``, ``rig snap``, the console) runs its plan
(a generator of ``goniofrost.capture.steps``, sent each step's result) through a ``PlanRunner``.
The one ``StepExecutor`` executes each step; the run emits the typed records of
``goniofrost.capture.records`` to its subscribers (journal, samples.csv, progress bar, live page).
A signal or stop request ends the run ``STOPPED_BY_OPERATOR`` (``SessionInterrupted``), a device
error ``FAULT``, a measurement or output error ``REFUSED`` (``SessionFault``); each time the axes
are stopped and confirmed (``rig.stop.stop_axes``) and the lamp switched off.
"""
from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from contextlib import contextmanager, nullcontext as _no_scope
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Sequence

from goniofrost.core.atomic_file import reason_of
from goniofrost.core.errors import GoniofrostError, OutputError
from goniofrost.rig.device_log import DeviceLog
from goniofrost.capture.executor import StepExecutor
from goniofrost.rig.stop import stop_text
from goniofrost.capture.records import (DeviceMessages, Event, EventKind, PlanEnded, RunEnd, RunStart, RunStatus,
                                        SafePoint, StepDone, StepFailed, StepStarting)
from goniofrost.capture.signals import Deferral, RunStopped, SessionInterrupted, signals_raise
from goniofrost.capture.run_journal import RunJournal
from goniofrost.capture.steps import CHECKPOINTS, Move, Phase, step_summary

__all__ = ["PlanRunner", "RunCount", "RunTexts", "SessionFault", "SessionInterrupted", "StepDone"]

log = logging.getLogger(__name__)


class SessionFault(GoniofrostError):
    """A device or a step failed mid-run; the axes were told to stop (the message says which
    confirmed it), the lamp to switch off, and the journal stays resumable."""


class SubscriberWarning(RuntimeWarning):
    """A subscriber failed on a record: the run goes on (a display must never stop a measurement)."""


@dataclass(frozen=True)
class RunTexts:
    """The words of a run's messages after a stop. ``saved()``: what is safe (None: where the
    run is journaled); ``resume``: what to do after a fault or a refusal; ``carry_on``: after an
    operator's stop (an option, not an instruction: a stopped move was stopped on purpose);
    ``samples``: the plan's samples, so that a failure at one names its angles."""

    saved: Callable[[], str] | None = None
    resume: str = "Fix the cause, then run the same command again"
    carry_on: str = "To carry on from here, run the same command again"
    samples: Sequence[dict] = ()


class RunCount(NamedTuple):
    """A run's counts for its RunStart and RunEnd: the plan's samples, those journaled, batches assessed."""

    planned: int = 0
    captured: int = 0
    batches: int = 0


class PlanRunner:
    """Run plans on ``hardware`` (a ``goniofrost.rig.contract.Hardware``); files go under
    ``folder``. ``journal``: a ``Journal`` (a ``RunJournal`` subscriber writes the run into it) or
    None (the run's records go to the subscribers and stay in ``run_start``/``run_end``); ``device_log``: the caller's (covering connect and release
    too), else the runner captures its own; ``program``: the name its runs are journaled under;
    ``texts``: its messages' words; ``count()``: its RunCount (default: a plan without samples);
    ``samples_only_safe``: the run may pause (a SafePoint) only before a sample's first move
    (default: before any step of a short plan)."""

    def __init__(self, hardware, folder, *, journal=None, device_log: DeviceLog | None = None,
                 program: str = "run", texts: RunTexts = RunTexts(), count: Callable[[], RunCount] = RunCount,
                 samples_only_safe: bool = False) -> None:
        self.hw, self.journal = hardware, journal
        self.devices = StepExecutor(hardware, folder)
        self.folder = self.devices.folder
        self.program, self.texts, self.count, self.samples_only_safe = program, texts, count, samples_only_safe
        self.run_start: RunStart | None = None
        self.run_end: RunEnd | None = None
        self._part: str | None = None      # the part of the plan under way (its last Phase step)
        self._given_log = device_log
        self._deferral, self._device_log = Deferral(), DeviceLog()  # replaced while running
        self._stopped: tuple = ([], None)  # (AxisStop list, lamp error) of the abort, if any
        self._subscribers: list = []       # (callback, required): see subscribe
        if journal is not None:
            self.subscribe(RunJournal(journal), required=True)

    def subscribe(self, callback: Callable[[Any], None], required: bool = False) -> None:
        """Hand every record of a run to ``callback``, in the order subscribed. A required one (the
        journal, a file the session keeps, as samples.csv) runs where no signal cuts in, and its
        error stops the run as the journal's does; another one's error is a SubscriberWarning and
        the run goes on."""
        self._subscribers.append((callback, required))

    # ----- the run ------------------------------------------------------------------------
    def execute_plan(self, plan, ending: Callable[[Any], tuple[RunStatus, str]] | None = None):
        """Run ``plan`` to its end; return what it returns (see module doc for how it may end).
        ``ending(value)``: (status, reason) of a run whose plan returned ``value`` (default: finished)."""
        count = self.count()
        run = self.journal.next_run() if self.journal is not None else 0
        self.run_start = RunStart(run, self.program, time.time(), count.planned, count.captured)
        self._emit(self.run_start, critical=False)
        self._event(EventKind.SESSION, f"{self.program} run {run} started with {count.captured} of {count.planned} "
                    f"samples done", data={"run": run})
        with signals_raise() as deferral, self._device_log_scope():
            self._deferral = deferral
            try:
                value = self._drive(plan)
            finally:
                self._emit(PlanEnded(), critical=False)
                self._journal_device_log(quiet=True)
        status, reason = ending(value) if ending else (RunStatus.FINISHED, f"{self.program} finished")
        self._end_run(status, reason)
        self._event(EventKind.SESSION, reason, data={"status": status.value})
        return value

    def _event(self, kind: EventKind, message: str, axis=None, data=None) -> None:
        self._emit(Event(kind, message, axis, data), critical=False)

    def _end_run(self, status: RunStatus, reason: str, **stopped) -> None:
        count = self.count()
        self.run_end = RunEnd(self.run_start.run, status, reason, count.planned, count.captured, count.batches,
                              self.run_start.started_utc, time.time(), **stopped)
        self._emit(self.run_end, critical=False)

    def _drive(self, plan):
        """Execute each step and send its result back into the plan; on any failure stop every
        axis, switch the lamp off and journal why. An error the plan raises is charged to the step
        before it."""
        from drivers.errors import DeviceError

        step = result = None
        try:
            while True:
                self.check_stop_request()
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
                                                f"{self.safe_text(self.texts.carry_on)}")
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

    def where(self, step) -> str:
        """' at plan sample N' / ' during Move' (' in the calibration') for the messages."""
        index = getattr(step, "index", None)
        if index is not None:
            return f" at plan sample {index}"
        if step is None:
            return " before the first step"
        part = f" in the {self._part}" if self._part else ""
        return f" during {type(step).__name__}{part}"

    def _safe_point(self, step) -> None:
        """At a safe point only (nothing under way): ask the hardware's pause gate (a server's
        ``pause_gate(where)``, if any) whether the run may continue (it blocks while the run is
        paused and raises SessionInterrupted when the run is stopped meanwhile), then hand the
        subscribers a SafePoint (a session's suspenders may wait there too)."""
        if self.samples_only_safe and not (isinstance(step, Move) and step.index is not None):
            return
        gate = getattr(self.hw, "pause_gate", None)
        if gate is not None:
            gate(self.where(step))
        self._emit(SafePoint(step), critical=False)

    def _stop_request(self) -> str | None:
        lock = getattr(self.hw, "rig_lock", None)
        return lock.stop_request() if lock is not None else None

    def check_stop_request(self) -> None:
        """A stop request of the rig lock, between steps (its SIGTERM interrupts a step itself)."""
        request = self._stop_request()
        if request is not None:
            raise SessionInterrupted(request)

    def _execute(self, step):
        """Emit the step as starting, execute it, emit it done with its summary; return its result."""
        self._emit(StepStarting(step))
        result = self.devices(step)
        summary = step_summary(step, result)
        if isinstance(step, CHECKPOINTS):  # what a resumed simulated run restores
            state = self.devices.checkpoint()
            summary = summary if state is None else {**summary, "sim_state": state}
        if isinstance(step, Phase):
            self._part = step.name
        done = StepDone(step, result, summary)
        self._emit(done, optional=False)
        self._journal_device_log()
        self._emit(done, required=False)
        return result

    def _emit(self, record, critical: bool = True, required: bool = True, optional: bool = True) -> None:
        """Hand ``record`` to the required subscribers (within the journal's critical section,
        unless not ``critical``: a signal waits until they are done; their error stops the run),
        then to the others (an error is a warning)."""
        if required:
            with self._deferral.critical() if critical else _no_scope():
                for callback in (c for c, needed in self._subscribers if needed):
                    callback(record)
        if not optional:
            return
        for callback in (c for c, needed in self._subscribers if not needed):
            try:
                callback(record)
            except Exception as exc:  # noqa: BLE001 - bluesky's rule: a subscriber never stops the run
                name = type(getattr(record, "step", record)).__name__
                log.warning("subscriber %s failed on %s: %s", getattr(callback, "__qualname__", callback), name, exc)
                warnings.warn(f"{name}: a subscriber failed: {exc}", SubscriberWarning, stacklevel=2)

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
                self._emit(StepFailed(step, "interrupted" if kind is EventKind.INTERRUPTED else "failed", detail),
                           critical=False, optional=False)
                self._event(kind, detail, axis=axis, data=data)
                self._event(EventKind.STOP, stop_text(stops), data={"stops": data["stops"]})
                self._event(EventKind.LAMP, "lamp off" if lamp_error is None else
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
        return f"{self.program} failed{self.where(step)}{self._angles(step)}: {exc}. {_remedy(exc)}{self.safe_text()}"

    def _angles(self, step) -> str:
        """' (theta_i 30.0 deg, theta_o 45.0 deg)' of the plan sample a step belongs to, if known."""
        index = getattr(step, "index", None)
        if index is None or not self.texts.samples:
            return ""
        s = self.texts.samples[index]
        return f" (theta_i {s['theta_i_deg']:.1f} deg, theta_o {s['theta_o_deg']:.1f} deg)"

    def safe_text(self, next_step: str | None = None) -> str:
        """What the abort did to the axes and the lamp, what is safe, and what to type next."""
        stops, lamp_error = self._stopped
        text = stop_text(stops)
        lamp = "the lamp is off" if lamp_error is None else "the lamp did not confirm it is off: it may still be on"
        check = " Check the axes named above before anything else moves." if any(not s.confirmed for s in stops) else ""
        return f"{text[0].upper()}{text[1:]}; {lamp}.{check} {self._saved_text()}. {next_step or self.texts.resume}"

    def _saved_text(self) -> str:
        if self.texts.saved is not None:
            return self.texts.saved()
        return f"The run is journaled in {self.journal.path}" if self.journal is not None else "Nothing was journaled"

    def _journal_device_log(self, quiet: bool = False) -> None:
        """Journal what the drivers logged (retries, failed stops, ...) since the last step.

        ``quiet``: on the way out of a failed run, never mask the original error.
        """
        if self.journal is None:  # nobody keeps them: the caller's device log keeps them
            return
        records = tuple(self._device_log.drain())
        if not records:
            return
        try:
            self._emit(DeviceMessages(records), critical=False)
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
