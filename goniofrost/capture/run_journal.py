"""The journal as a subscriber of a run's records: its runs, steps, events, samples and calibration.

``RunJournal`` is handed every record the engine core (``goniofrost.capture.plan_runner``) emits
and writes it into the journal (the core itself writes nothing): a ``runs`` row at ``RunStart``,
its end at ``RunEnd``; one ``steps`` row per step (``running`` at ``StepStarting``, ``done`` with the step's
summary at ``StepDone``, ``failed`` or ``interrupted`` at ``StepFailed``); an event per ``Event``
and per driver message (``DeviceMessages``). A ``Commit``'s sample (stamped with its commit time)
and a ``SaveCalibration``'s record are stored in the same transaction as their step's row, so a
kill never leaves one without the other.
"""
from __future__ import annotations

import dataclasses
import time

from goniofrost.capture.records import (DeviceMessages, Event, NotMeasuredRecord, RunEnd, RunStart, StepDone,
                                        StepFailed, StepStarting)
from goniofrost.capture.steps import Commit, SaveCalibration, step_detail


class RunJournal:
    """Journal the runs of ``journal`` (a ``Journal``)."""

    def __init__(self, journal) -> None:
        self.journal = journal
        self.run: int | None = None   # the run under way (its RunStart)
        self.row: int | None = None   # the row of the step under way

    def __call__(self, record) -> None:
        if isinstance(record, RunStart):
            self.journal.start_run(record)
            self.run = record.run
        elif isinstance(record, RunEnd):
            self.journal.end_run(record)
        elif isinstance(record, Event):
            self.journal.add_event(record.kind, record.message, axis=record.axis, data=record.data)
        elif isinstance(record, DeviceMessages):
            self.journal.add_device_records(record.records)
        elif isinstance(record, StepStarting):
            step = record.step
            self.row = self.journal.start_step(self.run, type(step).__name__, getattr(step, "index", None),
                                               step_detail(step))
        elif isinstance(record, StepDone):
            self._done(record)
            self.row = None
        elif isinstance(record, StepFailed) and self.row is not None:
            self.journal.end_step(self.row, record.ended, {"error": record.detail})
            self.row = None

    def _done(self, done: StepDone) -> None:
        step, ended = done.step, (self.row, done.summary)
        if isinstance(step, Commit):
            record = dataclasses.replace(step.record, committed_utc=time.time())
            if isinstance(record, NotMeasuredRecord):  # with its not_measured event
                self.journal.commit_not_measured(record, step=ended, message=not_measured_text(record))
            else:
                self.journal.commit_sample(record, step=ended)
        elif isinstance(step, SaveCalibration):
            self.journal.set_calibration(done.result.to_dict(), step=ended)
        else:
            self.journal.end_step(self.row, "done", done.summary)


def not_measured_text(record: NotMeasuredRecord) -> str:
    """The journal event's words for a sample not measured (readers use its data: the record)."""
    return f"sample {record.plan_index} not measured ({record.reason}): {record.why()}"
