"""The capture engine: the session plan on the engine core (``goniofrost.capture.plan_runner``).

``SessionEngine.run`` drives the steps of ``goniofrost.capture.session_steps`` through the
``PlanRunner`` (which journals each step, owns the stop of the axes, the lamp, the device log and
the run's ``RunStart``/``RunEnd``). On top of it the engine commits each sample in one transaction
the moment it is measured, appends it to samples.csv (a sample too dark or too bright to measure is committed
as not measured instead, with a ``not_measured`` event, and the capture goes on), journals the
calibration, lamp and homing events, times the parts of the session and shows a progress bar
with the ETA, and

* on SIGINT, SIGTERM or a stop request: stops every axis, switches the lamp off, records the
  event and the RunEnd (``stopped_by_operator``) and raises ``SessionInterrupted`` (the command
  exits 130); the journal stays resumable;
* on a device error (or a camera, calibration or output error): the same (``fault``/``refused``),
  and raises ``SessionFault`` with a one-line message (the command exits 2);
* at the end: the RunEnd says ``finished``, ``target_reached`` or ``plan_used_up``.

Every message says axis by axis what was confirmed at rest and what was not (an axis that did not
confirm its stop may still be moving towards its target), and whether the lamp confirmed it is
off; the journal has the same as ``stop`` and ``lamp`` events and in the RunEnd. On a simulated
rig, ``goniofrost.capture.rehearsal`` arms the fault drills and makes a resumed run measure what
one run would have.
"""
from __future__ import annotations

import dataclasses
import logging
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from goniofrost.rig.contract import Hardware
from goniofrost.rig.device_log import DeviceLog
from goniofrost.capture.journal import Journal, SamplesCsv, by_reason
from goniofrost.capture.records import NotMeasuredRecord, SampleRecord
from goniofrost.capture.plan_runner import PlanRunner, SessionFault, SessionInterrupted, StepDone
from goniofrost.capture.records import PHASE_KINDS, EventKind, RunStatus
from goniofrost.capture.rehearsal import Rehearsal
from goniofrost.capture.session_steps import SessionSpec, session_steps
from goniofrost.capture.suspension import SuspendWatch
from goniofrost.capture.steps import (Assess, Commit, Expose, Home, LampOff, LampOn, Move, Phase, SaveCalibration,
                                      WhiteCheck)
from goniofrost.capture.target import CONTINUE
from goniofrost.frost.stopping import REASON_PLAN as PLAN_USED_UP

__all__ = ["SessionEngine", "SessionFault", "SessionInterrupted", "SessionStats", "Hardware"]

log = logging.getLogger(__name__)


@dataclass
class SessionStats:
    """Times and counts of this run: motion and capture in session-clock seconds (simulated on a
    simulated rig), the parts of the session (``phase_s``: "calibration", "white_reference",
    "samples") and the whole run in real seconds."""

    motion_s: float = 0.0
    capture_s: float = 0.0
    captured: int = 0
    skipped: int = 0
    not_measured: int = 0   # of ``captured``: committed as not measured (too dark or saturated) in this run
    started_clock: float = 0.0
    ended_clock: float = 0.0
    wall_s: float = 0.0
    phase_s: dict = field(default_factory=dict)
    per_sample: list = field(default_factory=list)
    batches: list = field(default_factory=list)

    @property
    def calibration_s(self) -> float:
        """Real seconds spent calibrating in this run: a queue's white reference re-measured with the
        kept dark frames and flat field is calibration too (its own phase; the summary said
        "calibration 0.0 s" for it), and a full calibration after it when the lamp drifted."""
        return self.phase_s.get("calibration", 0.0) + self.phase_s.get("white_reference", 0.0)


class SessionEngine(PlanRunner):
    """Execute the session plan of ``spec`` (a SessionSpec, e.g. ``SessionSpec.from_inputs``) on
    ``hardware``, journaling into ``journal`` under ``session_dir``."""

    program = "capture"

    def __init__(self, spec: SessionSpec, hardware: Hardware, journal: Journal, session_dir,
                 progress: bool = True, device_log: DeviceLog | None = None) -> None:
        super().__init__(hardware, session_dir, journal=journal, device_log=device_log)
        self.spec = spec
        self.session_dir = self.folder
        self.csv = SamplesCsv(self.session_dir / "samples.csv", spec.batch_ends if spec.target is not None else ())
        self.progress = progress
        self.stats = SessionStats()
        self._phase: tuple | None = None   # (name, monotonic start) of the part under way
        self._bar = None
        self._initial = 0
        self._committed: SampleRecord | None = None  # the last sample journaled
        self.rehearsal = Rehearsal(self.devices, journal)  # a simulated rig's drills and state
        self.suspension = SuspendWatch(spec.suspenders, self.devices, journal, self._check_stop_request,
                                       lambda: self.run_start.run)  # the rig file's suspenders
        if getattr(hardware, "pause_gate", None) is not None:  # a server: its state follows the suspensions
            self.suspension.listen(hardware.pause_gate)
        self.reuse_calibration: dict | None = None  # another session's calibration record (a queue)
        self.progress_desc = "capture"  # the bar's label (a queue: its position and the sample)
        self.rerun = RERUN  # what to type to go on after a stop (a queue: the queue command, which resumes)
        self.step_journal = {Home: self._homed, LampOn: self._lamp_on, LampOff: self._lamp_off,
                             Move: self._moved, Expose: _exposed, Phase: self._phase_started,
                             SaveCalibration: self._calibration_saved, Assess: self._assessed,
                             WhiteCheck: self._white_checked, Commit: self._commit}
        self.subscribe(self._csv_line, required=True)   # samples.csv: kept with the journal's row
        self.subscribe(self._progressed)                 # the progress bar: a display

    # ----- the run ------------------------------------------------------------------------
    def run(self) -> SessionStats:
        """Capture every sample not yet journaled; return the stats of this run."""
        done = self.journal.done_indices()
        records = self.journal.samples()
        self.csv.rewrite(records)  # the journal is the truth; no torn line survives
        self.stats.skipped = self._initial = len(done)
        calibration = self._restore_calibration()
        reuse = self._reused_calibration() if calibration is None else None
        self.rehearsal.prepare(len(self.spec.samples), done, calibration is not None)
        plan = session_steps(self.spec, done, calibration=calibration,
                             measured={r.plan_index: r.rgb for r in records}, records=records, reuse=reuse,
                             not_measured=[r.plan_index for r in self.journal.not_measured()])
        wall0, self.stats.started_clock = time.monotonic(), self.hw.clock.now()
        self.execute_plan(plan)
        self.stats.ended_clock, self.stats.wall_s = self.hw.clock.now(), time.monotonic() - wall0
        return self.stats

    # ----- the engine core's questions --------------------------------------------------------
    def samples_planned(self) -> int:
        return len(self.spec.samples)

    def samples_captured(self) -> int:
        return len(self.journal.done_indices())

    def batches(self) -> int:
        return len(self.stats.batches)

    def completed(self, _value) -> tuple[RunStatus, str]:
        """finished, target_reached or plan_used_up, from the last batch's decision."""
        last, n = (self.stats.batches[-1] if self.stats.batches else None), len(self.spec.samples)
        if last is None:
            missing = by_reason(self.journal.not_measured())
            why = ", ".join(f"{reason} {len(indices)}" for reason, indices in missing.items())
            return RunStatus.FINISHED, "all samples captured" + (f" (not measured: {why})" if missing else "")
        from goniofrost.capture.target import statement

        if last["decision"] == PLAN_USED_UP:
            return RunStatus.PLAN_USED_UP, (f"all {n} samples captured: the plan was used up short of the target "
                                            f"{last['target']:g}: {statement(last)}")
        return RunStatus.TARGET_REACHED, (f"capture stopped after {last['samples']} of {n} samples: target "
                                          f"reached: {statement(last)}")

    def before_step(self, step) -> None:
        if isinstance(step, Move) and step.index is not None:
            self.rehearsal.before_sample(step.index)
            self.suspension.may_continue(step.index)  # the safe point: waits while suspended

    def after_journal(self) -> None:
        self.rehearsal.journal_struck()

    def at_safe_point(self, step) -> bool:
        """Before a sample's first move: the last sample's bracket is journaled, nothing is under way."""
        return isinstance(step, Move) and step.index is not None

    def run_scope(self):
        return self._progress(self._initial)

    def leaving(self) -> None:
        self._end_phase()

    def where(self, step) -> str:
        if getattr(step, "index", None) is not None or step is None:
            return super().where(step)
        part = f" in the {self._phase[0]}" if self._phase else ""
        return f"{super().where(step)}{part}"

    def failure_hint(self, step) -> str:
        index = getattr(step, "index", None)
        if index is None:
            return ""
        s = self.spec.samples[index]
        return f" (theta_i {s['theta_i_deg']:.1f} deg, theta_o {s['theta_o_deg']:.1f} deg)"

    def saved_text(self) -> str:
        n = len(self.spec.samples)
        try:
            done = f"{len(self.journal.done_indices())} of {n}"
        except Exception:  # noqa: BLE001 - an unreadable journal must not hide the stop report
            done = "the committed"
        return f"{done} samples are safe in {self.journal.path}"

    def resume_text(self) -> str:
        return f"Fix the cause, then run {self.rerun}"

    def continue_text(self) -> str:
        return f"Run {self.rerun} to continue"

    def _reused_calibration(self):
        """The calibration of another session this one may reuse (``reuse_calibration``: a queue's
        sample before), as a CalibrationRecord; None if there is none, or its arrays changed or its
        exposure ladder is not this rig's (then the session calibrates in full)."""
        from calib import CalibrationError, CalibrationRecord

        if self.reuse_calibration is None:
            return None
        try:
            record = CalibrationRecord.from_dict(self.reuse_calibration)
        except CalibrationError as exc:
            self.journal.add_event(EventKind.CALIBRATION, f"cannot reuse the queue's calibration ({exc}); "
                                   f"calibrating in full")
            return None
        if list(record.exposures_s) != list(self.spec.camera["exposures_s"]):
            self.journal.add_event(EventKind.CALIBRATION, "the queue's calibration has another exposure ladder; "
                                   "calibrating in full")
            return None
        return record

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
            self.journal.add_event(EventKind.CALIBRATION,
                                   f"cannot reuse the journaled calibration ({exc}); calibrating again")
            return None
        ladder = self.spec.camera["exposures_s"]
        if list(record.exposures_s) != list(ladder):  # the rig file's ladder changed
            self.journal.add_event(EventKind.CALIBRATION, f"exposure ladder changed from {record.exposures_s} to "
                                   f"{ladder}; calibrating again")
            return None
        return record

    # ----- what each step adds to the journal and the stats (returns the step's result summary) -----
    def _homed(self, step: Home, reached) -> dict:
        self.stats.motion_s += reached.seconds
        self.journal.add_event(EventKind.HOME, f"homed {', '.join(step.axes)}", data=reached.joints)
        return {"joints": reached.joints, "seconds": reached.seconds}

    def _lamp_on(self, _step: LampOn, photodiode: float) -> dict:
        self.journal.add_event(EventKind.LAMP, "lamp on", data={"photodiode": photodiode})
        return {"photodiode": photodiode}

    def _lamp_off(self, _step: LampOff, _result) -> dict:
        self.journal.add_event(EventKind.LAMP, "lamp off")
        return {}

    def _moved(self, _step: Move, reached) -> dict:
        self.stats.motion_s += reached.seconds
        return {"joints": reached.joints, "seconds": reached.seconds}

    def _phase_started(self, step: Phase, _result) -> dict:
        self._end_phase()
        self._phase = (step.name, time.monotonic())
        self.journal.add_event(PHASE_KINDS[step.name], PHASE_MESSAGES.get(step.name, f"{step.name} started"))
        return {}

    def _end_phase(self) -> None:
        if self._phase is not None:
            name, t0 = self._phase
            self.stats.phase_s[name] = self.stats.phase_s.get(name, 0.0) + time.monotonic() - t0
            self._phase = None

    def _calibration_saved(self, _step: SaveCalibration, record) -> dict:
        summary = self.rehearsal.with_state({"arrays": str(record.path), "sha256": record.sha256})
        self.journal.set_calibration(record.to_dict(), step=(self._row, summary))  # kept together with its state
        whole = self._phase is None or self._phase[0] != "white_reference"
        self.journal.add_event(EventKind.CALIBRATION, "dark, flat and white reference taken" if whole else
                               "white reference taken; dark frames and flat field reused",
                               data={"scale": record.scale.tolist(), "white": record.white, "reused": not whole})
        return summary

    def _white_checked(self, step: WhiteCheck, _result) -> dict:
        summary = dataclasses.asdict(step)
        then = ("dark frames and flat field reused" if step.decision == "reuse"
                else "the lamp drifted: calibrating in full")
        self.journal.add_event(EventKind.CALIBRATION, f"white reference re-measured: drift {100 * step.drift:.2f} % "
                               f"(limit {100 * step.limit:.2f} %): {then}", data=summary)
        return summary

    def _assessed(self, step: Assess, _result) -> dict:
        summary = dataclasses.asdict(step)
        self.stats.batches.append(summary)
        from goniofrost.capture.target import statement

        self.journal.add_event(EventKind.BATCH, f"batch {step.batch + 1}: {step.samples} samples, {statement(summary)}: "
                               f"{step.decision}", data=summary)
        return summary

    def _commit(self, step: Commit, _result) -> dict:
        record = dataclasses.replace(step.record, committed_utc=time.time())
        if isinstance(record, NotMeasuredRecord):
            return self._commit_not_measured(record)
        summary = self.rehearsal.with_state({"snr": record.snr, "status": record.status})
        # one durable transaction with its step and state (within _execute's critical section)
        self.journal.commit_sample(record, step=(self._row, summary))
        self._committed = record   # as journaled, with its commit time: samples.csv's line (_csv_line)
        self._counted(record)
        return summary

    def _commit_not_measured(self, record: NotMeasuredRecord) -> dict:
        """Journal a sample too dark or too bright to measure and its ``not_measured`` event (no samples.csv line: it
        has no value)."""
        summary = self.rehearsal.with_state({"snr": record.best_snr, "status": str(record.reason)})
        # the record, its step and its event in one durable transaction
        self.journal.commit_not_measured(record, step=(self._row, summary), message=not_measured_text(record))
        self.stats.not_measured += 1
        self._counted(record)
        return summary

    def _counted(self, record) -> None:
        self.stats.captured += 1
        self.stats.capture_s += record.capture_s
        if isinstance(record, SampleRecord):
            self.stats.per_sample.append({"index": record.plan_index, "snr": record.snr})

    # ----- subscribers: what follows the journal ------------------------------------------------
    def _csv_line(self, done: StepDone) -> None:
        """samples.csv gets each measured sample, as journaled (a sample not measured has no value)."""
        if isinstance(done.step, Commit) and isinstance(done.step.record, SampleRecord):
            self.csv.append(self._committed)

    def _progressed(self, done: StepDone) -> None:
        """The bar counts each sample done; a capture stopped early ends it at the count captured."""
        if self._bar is None:
            return
        if isinstance(done.step, Commit):
            self._bar.update(1)
        elif isinstance(done.step, Assess) and done.step.decision not in (CONTINUE, PLAN_USED_UP):
            self._bar.total = self._bar.n  # not "15/40"
            self._bar.refresh()

    @contextmanager
    def _progress(self, initial: int):
        from tqdm import tqdm

        from goniofrost.core.progress import show_progress

        total = len(self.spec.samples)
        with tqdm(total=total, initial=initial, unit="sample", desc=self.progress_desc, file=sys.stderr,
                  disable=not show_progress(self.progress), dynamic_ncols=True) as bar:
            self._bar = bar
            try:
                yield bar
            finally:
                self._bar = None


RERUN = "the same command with --resume"  # what a stopped capture tells the user to type next

PHASE_MESSAGES = {"calibration": "calibration started: dark frames, flat field, white reference",
                  "white_reference": "white reference re-measured with the kept dark frames and flat field",
                  "samples": "sample capture started"}


def not_measured_text(record: NotMeasuredRecord) -> str:
    """The journal event's words for a sample not measured (readers use its data: the record)."""
    return f"sample {record.plan_index} not measured ({record.reason}): {record.why()}"


def _exposed(_step: Expose, frame) -> dict:
    return {"path": str(frame.path), "lamp_relative": frame.lamp_relative, "seconds": frame.seconds}
