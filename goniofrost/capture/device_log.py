"""The drivers' log during a capture session, kept for the journal's device events."""
from __future__ import annotations

import logging
from contextlib import contextmanager


class DeviceLog(logging.Handler):
    """Collect the drivers' log records (INFO and up) from any thread; the engine journals them
    from its own thread (an SQLite connection belongs to the thread that made it)."""

    LOGGERS = ("drivers", "calib")

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self._records: list = []

    def emit(self, record: logging.LogRecord) -> None:
        self._records.append(record)  # list.append is atomic under the GIL

    def drain(self) -> list:
        records, self._records = self._records, []
        return records

    @classmethod
    @contextmanager
    def capture(cls):
        handler = cls()
        loggers = [logging.getLogger(name) for name in cls.LOGGERS]
        levels = [lg.level for lg in loggers]
        for lg in loggers:
            lg.addHandler(handler)
            if lg.getEffectiveLevel() > logging.INFO:
                lg.setLevel(logging.INFO)
        try:
            yield handler
        finally:
            for lg, level in zip(loggers, levels):
                lg.removeHandler(handler)
                lg.setLevel(level)
