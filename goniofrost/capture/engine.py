"""The capture engine: the session plan on the engine core (``goniofrost.capture.plan_runner``).

``SessionEngine.run`` drives the steps of ``goniofrost.capture.session_steps`` through a
``PlanRunner`` and subscribes to its records: it appends each sample to samples.csv, journals the
calibration, lamp and homing events, arms a simulated rig's drills, waits on the suspenders at each
sample's safe point, and shows a progress bar. A stop (signal, stop request) raises
``SessionInterrupted`` (exit 130); a device, camera, calibration or output error raises
``SessionFault`` (exit 2); either way the axes are stopped, the lamp is off, and the message and
journal say what each confirmed. The journal stays resumable.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from goniofrost.rig.contract import Hardware
from goniofrost.rig.device_log import DeviceLog
from goniofrost.capture.journal import Journal, SamplesCsv, by_reason
from goniofrost.capture.options import SessionOptions
from goniofrost.capture.plan_runner import PlanRunner, RunCount, RunTexts, SessionFault, SessionInterrupted
from goniofrost.capture.progress_bar import ProgressBar
from goniofrost.capture.records import (PHASE_KINDS, EventKind, NotMeasuredRecord, PlanEnded, RunStatus, SafePoint,
                                        SampleRecord, StepDone, StepFailed)
from goniofrost.capture.rehearsal import Rehearsal
from goniofrost.capture.session_steps import SessionSpec, session_steps
from goniofrost.capture.suspension import SuspendWatch
from goniofrost.capture.steps import Assess, Commit, Home, LampOff, LampOn, Move, Phase, SaveCalibration, WhiteCheck
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


class SessionEngine:
    """Execute the session plan of ``spec`` (a SessionSpec, e.g. ``SessionSpec.from_inputs``) on
    ``hardware`` through a PlanRunner, journaling into ``journal`` under ``session_dir``;
    ``options``: its progress bar, what to type after a stop, a calibration to reuse
    (``goniofrost.capture.options.SessionOptions``)."""

    def __init__(self, spec: SessionSpec, hardware: Hardware, journal: Journal, session_dir,
                 options: SessionOptions = SessionOptions(), device_log: DeviceLog | None = None) -> None:
        texts = RunTexts(saved=self._saved_text, resume=f"Fix the cause, then run {options.rerun}",
                         carry_on=f"Run {options.rerun} to continue", samples=spec.samples)
        self.runner = PlanRunner(hardware, session_dir, journal=journal, device_log=device_log, program="capture",
                                 texts=texts, count=self._count, samples_only_safe=True)
        self.spec, self.journal, self.hw, self.options = spec, journal, hardware, options
        self.session_dir = self.runner.folder
        self.csv = SamplesCsv(self.session_dir / "samples.csv", spec.batch_ends if spec.target is not None else ())
        self.stats = SessionStats()
        self._phase: tuple | None = None   # (name, monotonic start) of the part under way
        devices = self.runner.devices
        self.rehearsal = Rehearsal(devices, journal)  # a simulated rig's drills and state
        self.suspension = SuspendWatch(spec.suspenders, devices, journal, self.runner.check_stop_request,
                                       lambda: self.runner.run_start.run)  # the rig file's suspenders
        if getattr(hardware, "pause_gate", None) is not None:  # a server: its state follows the suspensions
            self.suspension.listen(hardware.pause_gate)
        self.runner.subscribe(self._journaled, required=True)  # events and stats, after the step's own row
        self.runner.subscribe(self._csv_line, required=True)   # samples.csv: kept with the journal's row

    # ----- the run ------------------------------------------------------------------------
    def run(self) -> SessionStats:
        """Capture every sample not yet journaled; return the stats of this run."""
        done = self.journal.done_indices()
        records = self.journal.samples()
        self.csv.rewrite(records)  # the journal is the truth; no torn line survives
        self.stats.skipped = len(done)
        self.runner.subscribe(ProgressBar(len(self.spec.samples), Commit, unit="sample",
                                          desc=self.options.progress_desc, show=self.options.progress,
                                          initial=len(done)))  # a display
        calibration = self._restore_calibration()
        reuse = self._reused_calibration() if calibration is None else None
        self.rehearsal.prepare(len(self.spec.samples), done, calibration is not None)
        plan = session_steps(self.spec, done, calibration=calibration,
                             measured={r.plan_index: r.rgb for r in records}, records=records, reuse=reuse,
                             not_measured=[r.plan_index for r in self.journal.not_measured()])
        wall0, self.stats.started_clock = time.monotonic(), self.hw.clock.now()
        self.runner.execute_plan(plan, ending=self._completed)
        self.stats.ended_clock, self.stats.wall_s = self.hw.clock.now(), time.monotonic() - wall0
        return self.stats

    # ----- what the engine core is handed --------------------------------------------------------
    def _count(self) -> RunCount:
        return RunCount(len(self.spec.samples), len(self.journal.done_indices()), len(self.stats.batches))

    def _completed(self, _value) -> tuple[RunStatus, str]:
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

    def _saved_text(self) -> str:
        n = len(self.spec.samples)
        try:
            done = f"{len(self.journal.done_indices())} of {n}"
        except Exception:  # noqa: BLE001 - an unreadable journal must not hide the stop report
            done = "the committed"
        return f"{done} samples are safe in {self.journal.path}"

    def _reused_calibration(self):
        """The calibration of another session this one may reuse (``options.reuse``: a queue's
        sample before), as a CalibrationRecord; None if there is none, or its arrays changed or its
        exposure ladder is not this rig's (then the session calibrates in full)."""
        from calib import CalibrationError, CalibrationRecord

        if self.options.reuse is None:
            return None
        try:
            record = CalibrationRecord.from_dict(self.options.reuse.record)
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

    # ----- subscribers: what follows the journal's row of each step -----------------------------
    def _journaled(self, record) -> None:
        """A sample's safe point, the events each step adds to the journal, the stats, and drills struck."""
        if isinstance(record, SafePoint):  # before a sample's first move: nothing is under way
            self.rehearsal.before_sample(record.step.index)
            self.suspension.may_continue(record.step.index)  # waits while suspended
        elif isinstance(record, StepDone):
            self._step_done(record.step, record.result, record.summary)
            self.rehearsal.journal_struck()
        elif isinstance(record, StepFailed):
            self.rehearsal.journal_struck()
        elif isinstance(record, PlanEnded):
            self._end_phase()  # the time of the part under way

    def _step_done(self, step, result, summary: dict) -> None:
        if isinstance(step, (Home, Move)):
            self.stats.motion_s += result.seconds
        if isinstance(step, Home):
            self.journal.add_event(EventKind.HOME, f"homed {', '.join(step.axes)}", data=result.joints)
        elif isinstance(step, LampOn):
            self.journal.add_event(EventKind.LAMP, "lamp on", data={"photodiode": result})
        elif isinstance(step, LampOff):
            self.journal.add_event(EventKind.LAMP, "lamp off")
        elif isinstance(step, Phase):
            self._end_phase()
            self._phase = (step.name, time.monotonic())
            self.journal.add_event(PHASE_KINDS[step.name], PHASE_MESSAGES.get(step.name, f"{step.name} started"))
        elif isinstance(step, SaveCalibration):
            whole = self._phase is None or self._phase[0] != "white_reference"
            self.journal.add_event(EventKind.CALIBRATION, "dark, flat and white reference taken" if whole else
                                   "white reference taken; dark frames and flat field reused",
                                   data={"scale": result.scale.tolist(), "white": result.white, "reused": not whole})
        elif isinstance(step, WhiteCheck):
            then = ("dark frames and flat field reused" if step.decision == "reuse"
                    else "the lamp drifted: calibrating in full")
            self.journal.add_event(EventKind.CALIBRATION, f"white reference re-measured: drift {100 * step.drift:.2f} % "
                                   f"(limit {100 * step.limit:.2f} %): {then}", data=summary)
        elif isinstance(step, Assess):
            self._assessed(step, summary)
        elif isinstance(step, Commit):
            self._counted(step.record)

    def _end_phase(self) -> None:
        if self._phase is not None:
            name, t0 = self._phase
            self.stats.phase_s[name] = self.stats.phase_s.get(name, 0.0) + time.monotonic() - t0
            self._phase = None

    def _assessed(self, step: Assess, summary: dict) -> None:
        from goniofrost.capture.target import statement

        self.stats.batches.append(summary)
        self.journal.add_event(EventKind.BATCH, f"batch {step.batch + 1}: {step.samples} samples, {statement(summary)}: "
                               f"{step.decision}", data=summary)

    def _counted(self, record) -> None:
        self.stats.captured += 1
        self.stats.capture_s += record.capture_s
        if isinstance(record, NotMeasuredRecord):
            self.stats.not_measured += 1
        else:
            self.stats.per_sample.append({"index": record.plan_index, "snr": record.snr})

    def _csv_line(self, record) -> None:
        """samples.csv gets each measured sample, as journaled (a sample not measured has no value)."""
        if isinstance(record, StepDone) and isinstance(record.step, Commit) and \
                isinstance(record.step.record, SampleRecord):
            self.csv.append(record.step.record)


PHASE_MESSAGES = {"calibration": "calibration started: dark frames, flat field, white reference",
                  "white_reference": "white reference re-measured with the kept dark frames and flat field",
                  "samples": "sample capture started"}
