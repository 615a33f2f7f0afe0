"""Signals during a capture session: SIGINT/SIGTERM become ``SessionInterrupted``, except that a
journal commit is finished first and the stopping of the axes cannot be cut short."""
from __future__ import annotations

import signal
from contextlib import contextmanager


class SessionInterrupted(BaseException):
    """SIGINT/SIGTERM stopped the session (exit status 130); the engine's message says how each
    axis and the lamp took the stop.

    A BaseException, like KeyboardInterrupt, so that no ``except Exception`` swallows it.
    """


class RunStopped(SessionInterrupted):
    """A stop that was carried out: every axis was told to stop and the lamp to switch off, and
    the message says what each confirmed (``plan_runner``, ``holder``)."""


class Deferral:
    """Signal state: raise at once, or hold the signal while a commit is in progress."""

    def __init__(self) -> None:
        self.in_critical = False
        self.pending: int | None = None

    def handle(self, signum, _frame) -> None:
        if self.in_critical:
            self.pending = signum
            return
        raise SessionInterrupted(signal.Signals(signum).name)

    @contextmanager
    def ignored(self):
        """Hold signals and then drop them (the session is already stopping)."""
        self.in_critical = True
        try:
            yield
        finally:
            self.in_critical, self.pending = False, None

    @contextmanager
    def critical(self):
        self.in_critical = True
        try:
            yield
        finally:
            self.in_critical = False
            if self.pending is not None:
                signum, self.pending = self.pending, None
                raise SessionInterrupted(signal.Signals(signum).name)


@contextmanager
def signals_raise():
    """Turn SIGINT and SIGTERM into SessionInterrupted for the duration (main thread only)."""
    deferral = Deferral()
    wanted = (signal.SIGINT, signal.SIGTERM)
    try:
        previous = {s: signal.signal(s, deferral.handle) for s in wanted}
    except ValueError:  # not the main thread: signals stay with their owner
        previous = {}
    try:
        yield deferral
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
