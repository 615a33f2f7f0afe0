"""Suspended runs: the engine's "may I continue?" at the safe point between samples.

``SuspendWatch.may_continue(index)`` is called before each plan sample's move. When one of the rig
file's suspenders (``goniofrost.rig.suspenders``) is violated the run is suspended: journaled
(``Journal.start_suspension``), said on the terminal, and the devices read again every ``poll_s``
of the session clock until every condition held clear for ``hold_clear_s`` (and, with ``resume:
operator``, ``resume()`` was called). A stop ends the wait; a device silent for ``give_up_s`` ends
the run as a fault. ``subscribe`` hands out each ``Reading``; ``listen`` tells when a suspension
starts and ends.
"""
from __future__ import annotations

import sys
import threading
from typing import Callable

from drivers.errors import DeviceTimeout
from goniofrost.capture.records import SuspensionEnd
from goniofrost.rig.suspenders import Reading, ResumeMode, SuspendReason, Suspenders


class SuspendWatch:
    """The suspenders of one engine run: ``suspenders`` (None: never suspends), ``executor`` (a
    StepExecutor: its ``read_conditions`` and ``hw.clock``), ``journal`` (a Journal or None),
    ``check_stop()`` raising when the run must stop, ``run()`` -> the run's number."""

    def __init__(self, suspenders: Suspenders | None, executor, journal, check_stop: Callable[[], None],
                 run: Callable[[], int]) -> None:
        self.suspenders, self.devices, self.journal = suspenders, executor, journal
        self.check_stop, self.run = check_stop, run
        self.reference: float | None = None  # the run's first photodiode reading
        self.suspended: SuspendReason | None = None
        self.waited = 0.0  # session seconds of the suspension under way (or the last)
        self._resumed = threading.Event()
        self._subscribers: list[Callable[[Reading], None]] = []
        self._listeners: list = []

    @staticmethod
    def say(text: str) -> None:
        """Tell the operator (the terminal; the journal has the same as ``suspend`` events)."""
        print(f"goniofrost: {text}", file=sys.stderr, flush=True)

    def subscribe(self, callback: Callable[[Reading], None]) -> None:
        """Hand ``callback`` every Reading taken while suspended (a live view, a test's operator)."""
        self._subscribers.append(callback)

    def listen(self, listener) -> None:
        """Tell ``listener`` of each suspension: ``listener.suspended(watch, reason, text)`` once it
        is journaled, ``listener.resumed(watch, end, text)`` when it ends however (same thread)."""
        self._listeners.append(listener)

    def resume(self) -> None:
        """The operator's resume: a run waiting for it goes on once its conditions held clear."""
        self._resumed.set()

    def may_continue(self, index: int) -> None:
        """Return at once when every condition is clear; else wait, journaled, until the run may go on."""
        if self.suspenders is None:
            return
        reading = self._read()
        reason = self.suspenders.check(reading)
        if reason is not None:
            self._wait(reason, reading, index)

    def _read(self) -> Reading:
        reading = self.devices.read_conditions(self.suspenders, self.reference)
        if self.reference is None and reading.photodiode:
            self.reference = reading.photodiode
        return reading

    def _wait(self, reason: SuspendReason, reading: Reading, index: int) -> None:
        """Suspended for ``reason`` before plan sample ``index``: poll until it may go on."""
        self.suspended, self._resumed = reason, threading.Event()
        text = f"run suspended before plan sample {index}: {reason} ({describe(reason, reading, self.suspenders)})"
        self.say(text)
        row = None if self.journal is None else self.journal.start_suspension(self.run(), reason, index, text)
        for listener in self._listeners:
            listener.suspended(self, reason, text)
        self.waited, end = 0.0, SuspensionEnd.STOPPED
        try:
            end = self._poll()
        except DeviceTimeout:
            end = SuspensionEnd.GAVE_UP
            raise
        finally:
            self.suspended = None
            words = {SuspensionEnd.STOPPED: "run stopped while suspended",
                     SuspensionEnd.GAVE_UP: "run ended: a device stayed silent while suspended"}.get(end, "run resumed")
            words = f"{words} after {self.waited:g} s ({end})"
            self.say(words)
            if row is not None:
                self.journal.end_suspension(row, end, self.waited, words)
            for listener in self._listeners:
                listener.resumed(self, end, words)

    def _poll(self) -> SuspensionEnd:
        """How the suspension ended, once every condition held clear for hold_clear_s since the first
        clear reading (and the operator resumed); ``waited``: the session seconds so far."""
        s, clear_since, silent = self.suspenders, None, 0.0
        while True:
            self.check_stop()
            if clear_since is not None and self.waited - clear_since >= s.hold_clear_s:
                if s.resume is ResumeMode.AUTO:
                    return SuspensionEnd.RESUMED
                if self._resumed.is_set():
                    return SuspensionEnd.OPERATOR
            self.devices.hw.clock.sleep(s.poll_s)
            self.waited += s.poll_s
            reading = self._read()
            for callback in self._subscribers:
                callback(reading)
            clear = s.check(reading) is None
            clear_since = (clear_since if clear_since is not None else self.waited) if clear else None
            silent = silent + s.poll_s if reading.silent is not None else 0.0
            if silent >= s.give_up_s:
                raise DeviceTimeout(reading.silent, "answer the suspenders' reading", None,
                                    f"no answer for {silent:g} s while the run was suspended")


def describe(reason: SuspendReason, reading: Reading, suspenders: Suspenders) -> str:
    """Why ``reading`` suspended a run, in words for the terminal and the journal's event."""
    if reason is SuspendReason.DEVICE_SILENT:
        return f"{reading.silent} does not answer"
    if reason is SuspendReason.INTERLOCK_OPEN:
        return f"the interlock input {suspenders.interlock['input']} of {suspenders.interlock['device']} is open"
    if reason is SuspendReason.LAMP_LOW:
        return f"photodiode {reading.photodiode:.3f} of nominal, below the floor {suspenders.lamp_floor:g}"
    change = reading.photodiode / reading.reference - 1.0
    return (f"photodiode {reading.photodiode:.3f} of nominal, {100 * change:+.1f} % from the run's first reading "
            f"{reading.reference:.3f} (limit {100 * suspenders.lamp_drift:g} %)")
