"""The devices' log during a capture session: kept for the journal, never printed on the terminal.

Drivers retry, fail to stop, and pymodbus (client and simulated server) logs errors with hex
dumps of the last frames; Python would print all of it on the terminal (its last-resort handler)
around the one-line error the command shows. While a session holds the devices, ``DeviceLog``
collects those records instead (INFO and up, no propagation to other handlers) and
the capture stores them in the session's journal as ``device`` events
(``goniofrost.capture.journal.Journal.add_device_log``).
"""
from __future__ import annotations

import logging
from contextlib import contextmanager


class DeviceLog(logging.Handler):
    """Collect the device-side log records (INFO and up) from any thread; the engine journals them
    from its own thread (an SQLite connection belongs to the thread that made it)."""

    # logger -> lowest level kept: the drivers, the simulated devices, the rig (the stop path, the
    # release) and the capture layer (a journal write that failed on the way out) from INFO; the
    # protocol libraries from WARNING (not "Server listening.")
    LOGGERS = {"drivers": logging.INFO, "calib": logging.INFO, "sim": logging.INFO, "goniofrost.rig": logging.INFO,
               "goniofrost.capture": logging.INFO, "pymodbus": logging.WARNING, "dynamixel_sdk": logging.WARNING}

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
        """Collect the LOGGERS' records for the duration; they reach no other handler meanwhile."""
        handler = cls()
        loggers = [logging.getLogger(name) for name in cls.LOGGERS]
        saved = [(lg.level, lg.propagate) for lg in loggers]
        for lg in loggers:
            lg.addHandler(handler)
            lg.propagate = False  # not to the terminal: the journal has them
            lg.setLevel(cls.LOGGERS[lg.name])
        try:
            yield handler
        finally:
            for lg, (level, propagate) in zip(loggers, saved):
                lg.removeHandler(handler)
                lg.setLevel(level)
                lg.propagate = propagate
