"""The session journal: every captured sample, committed to SQLite the moment it is measured.

``DIR/session.sqlite`` (WAL, ``synchronous=FULL``: a committed sample survives SIGKILL and power
loss) holds the session's meta data, its calibration, one row per measured sample and per sample
not measured (keyed by plan index: never stored twice), the events, the runs (``RunStart`` /
``RunEnd``) and every step of the plan as it runs. ``samples.csv`` beside it is a derived view
(``SamplesCsv``), rewritten from the journal on resume. The tables:
docs/reference/file-formats.md."""
from __future__ import annotations

import json
import os
import sqlite3
import time
from contextlib import contextmanager
from dataclasses import asdict, fields
from pathlib import Path

from calib.measurement import NotMeasuredReason
from goniofrost.core.atomic_file import output_errors, write_text_atomic
from goniofrost.core.errors import GoniofrostError, OutputError
from goniofrost.capture.records import (EventKind, NotMeasuredRecord, RunEnd, RunStart, RunStatus,  # noqa: F401
                                       SampleRecord, SessionLabel, Suspension, SuspensionEnd, json_limits)
from goniofrost.rig.stop import AxisStop
from goniofrost.frost import samples_file

FORMAT_VERSION = 1
CSV_COLUMNS = samples_file.SESSION_COLUMNS  # samples.csv: the format is goniofrost.frost.samples_file

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS calibration (
    id INTEGER PRIMARY KEY CHECK (id = 1), record TEXT NOT NULL, created_utc REAL NOT NULL);
CREATE TABLE IF NOT EXISTS samples (
    plan_index INTEGER PRIMARY KEY, cell INTEGER NOT NULL, status TEXT NOT NULL,
    theta_h_deg REAL NOT NULL, theta_d_deg REAL NOT NULL, phi_d_deg REAL NOT NULL,
    r REAL NOT NULL, g REAL NOT NULL, b REAL NOT NULL,
    sigma_r REAL NOT NULL, sigma_g REAL NOT NULL, sigma_b REAL NOT NULL, snr REAL NOT NULL,
    joints TEXT NOT NULL, exposures_s TEXT NOT NULL, frames_taken INTEGER NOT NULL,
    frames_skipped INTEGER NOT NULL, raw_paths TEXT NOT NULL, lamp_relative REAL NOT NULL,
    move_s REAL NOT NULL, capture_s REAL NOT NULL, started_utc REAL NOT NULL,
    committed_utc REAL NOT NULL);
CREATE TABLE IF NOT EXISTS not_measured (
    plan_index INTEGER PRIMARY KEY, cell INTEGER NOT NULL, reason TEXT NOT NULL,
    theta_h_deg REAL NOT NULL, theta_d_deg REAL NOT NULL, phi_d_deg REAL NOT NULL,
    snr_r REAL NOT NULL, snr_g REAL NOT NULL, snr_b REAL NOT NULL, min_snr REAL NOT NULL,
    longest_exposure_s REAL NOT NULL, upper_r REAL NOT NULL, upper_g REAL NOT NULL, upper_b REAL NOT NULL,
    lower_r REAL NOT NULL DEFAULT 0, lower_g REAL NOT NULL DEFAULT 0, lower_b REAL NOT NULL DEFAULT 0,
    joints TEXT NOT NULL, exposures_s TEXT NOT NULL, frames_taken INTEGER NOT NULL,
    frames_skipped INTEGER NOT NULL, raw_paths TEXT NOT NULL, lamp_relative REAL NOT NULL,
    move_s REAL NOT NULL, capture_s REAL NOT NULL, started_utc REAL NOT NULL,
    committed_utc REAL NOT NULL);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, t_utc REAL NOT NULL, kind TEXT NOT NULL,
    axis TEXT, message TEXT NOT NULL, data TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS steps (
    id INTEGER PRIMARY KEY AUTOINCREMENT, run INTEGER NOT NULL, kind TEXT NOT NULL, plan_index INTEGER,
    detail TEXT NOT NULL, status TEXT NOT NULL, result TEXT NOT NULL, started_utc REAL NOT NULL,
    ended_utc REAL);
CREATE TABLE IF NOT EXISTS runs (
    run INTEGER PRIMARY KEY, program TEXT NOT NULL, started_utc REAL NOT NULL, samples_planned INTEGER NOT NULL,
    samples_done INTEGER NOT NULL, status TEXT, end_record TEXT);
CREATE TABLE IF NOT EXISTS suspensions (
    id INTEGER PRIMARY KEY AUTOINCREMENT, run INTEGER NOT NULL, reason TEXT NOT NULL, plan_index INTEGER,
    started_utc REAL NOT NULL, ended_utc REAL, waited_s REAL, end_kind TEXT);
"""
STEP_STATUSES = ("running", "done", "failed", "interrupted")


class JournalError(GoniofrostError):
    """A session journal that cannot be created, opened or continued."""


def by_reason(not_measured) -> dict:
    """{reason (its value): [plan indices]} of NotMeasuredRecords, reasons in order of first sight."""
    grouped: dict = {}
    for d in not_measured:
        grouped.setdefault(str(d.reason), []).append(d.plan_index)
    return grouped


class Journal:
    """An open session journal (``Journal.create`` for a new session, ``Journal.open`` to resume)."""

    def __init__(self, path: Path, connection: sqlite3.Connection) -> None:
        self.path = path
        self._db = connection

    # ----- opening ------------------------------------------------------------------------
    @classmethod
    def create(cls, path, meta: dict) -> "Journal":
        """Start a new journal at ``path`` holding ``meta`` (str -> JSON-serialisable)."""
        path = Path(path)
        if path.exists():
            raise JournalError(f"{path}: a session journal already exists; pass --resume to continue it "
                               f"or choose a new --session folder")
        try:
            journal = cls(path, _connect(path))
            try:
                with journal._transaction() as db:
                    db.executemany("INSERT INTO meta VALUES (?, ?)",
                                   [(k, json.dumps(v)) for k, v in {**meta, "format_version": FORMAT_VERSION}.items()])
            except BaseException:
                journal.close()
                raise
        except BaseException:  # no half-made journal may block the next attempt
            for leftover in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
                leftover.unlink(missing_ok=True)
            raise
        return journal

    @classmethod
    def open(cls, path, read_only: bool = False) -> "Journal":
        """Open an existing journal to continue it; ``read_only``: to check it first without
        writing or creating any file (``connect_read_only``; no other process may be writing it)."""
        path = Path(path)
        if not path.is_file():
            raise JournalError(f"{path}: no session journal to resume (expected a file made by goniofrost capture)")
        journal = cls(path, connect_read_only(path) if read_only else _connect(path))
        try:
            version = journal.meta().get("format_version")
        except sqlite3.DatabaseError as exc:   # a read-only connection reads the file only now
            journal.close()
            raise JournalError(f"{path}: not a usable session journal ({exc})") from None
        if version != FORMAT_VERSION:
            journal.close()
            raise JournalError(f"{path}: meta.format_version: expected {FORMAT_VERSION}, found {version!r}")
        return journal

    @classmethod
    def open_read_only(cls, path) -> "Journal":
        """Open a journal that may be live for reading only (a monitor): it cannot write, and it
        creates no file beside the journal (``connect_read_only``)."""
        path = Path(path)
        return cls(path, connect_read_only(path))

    @contextmanager
    def snapshot(self):
        """One read transaction: every read inside sees the same moment of the journal."""
        self._db.execute("BEGIN")
        try:
            yield self
        finally:
            self._db.execute("COMMIT")

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ----- reading ------------------------------------------------------------------------
    def meta(self) -> dict:
        """The session's meta data (key -> decoded JSON value)."""
        return {k: json.loads(v) for k, v in self._db.execute("SELECT key, value FROM meta")}

    def label(self) -> SessionLabel:
        """Who measured what, where (meta ``label``; a journal from before labels: an empty label)."""
        row = self._db.execute("SELECT value FROM meta WHERE key = 'label'").fetchone()
        return SessionLabel.from_dict(None if row is None else json.loads(row[0]))

    def calibration(self) -> dict | None:
        """The stored calibration record, or None before calibration."""
        row = self._db.execute("SELECT record FROM calibration WHERE id = 1").fetchone()
        return None if row is None else json.loads(row[0])

    def samples(self) -> list[SampleRecord]:
        """Every committed sample, in plan order."""
        cursor = self._db.execute("SELECT * FROM samples ORDER BY plan_index")
        names = [c[0] for c in cursor.description]
        return [_record_from_row(dict(zip(names, row))) for row in cursor]

    def not_measured(self) -> list[NotMeasuredRecord]:
        """Every plan sample committed as not measured, in plan order (a read-only view of a journal
        from before the table: [])."""
        try:
            cursor = self._db.execute("SELECT * FROM not_measured ORDER BY plan_index")
        except sqlite3.OperationalError:
            return []
        names = [c[0] for c in cursor.description]
        return [_not_measured_from_row(dict(zip(names, row))) for row in cursor]

    def done_indices(self) -> set[int]:
        """Plan indices of the samples already committed: measured or not measured (both are done:
        a resume takes neither again)."""
        done = {row[0] for row in self._db.execute("SELECT plan_index FROM samples")}
        return done | {r.plan_index for r in self.not_measured()}

    def events(self) -> list[dict]:
        """Every event in order: dicts with t_utc, kind (an EventKind; a kind this version does not
        know stays a str), axis, message, data."""
        rows = self._db.execute("SELECT t_utc, kind, axis, message, data FROM events ORDER BY id")
        return [{"t_utc": t, "kind": _event_kind(k), "axis": a, "message": m, "data": json.loads(d)}
                for t, k, a, m, d in rows]

    def steps(self) -> list[dict]:
        """Every journaled plan step in order: dicts with id, run, kind, plan_index, detail, status,
        result, started_utc, ended_utc (``detail`` and ``result`` decoded from JSON)."""
        return _step_rows(self._db.execute("SELECT * FROM steps ORDER BY id"))

    def recent_steps(self) -> list[dict]:
        """The last step row and the last Move that ended done, oldest first, decoded as ``steps``
        decodes them: what a live view needs without reading thousands of rows several times a second."""
        return _step_rows(self._db.execute(
            "SELECT * FROM steps WHERE id IN ((SELECT MAX(id) FROM steps), "
            "(SELECT MAX(id) FROM steps WHERE kind = 'Move' AND status = 'done')) ORDER BY id"))

    def runs(self) -> list[tuple[RunStart, RunEnd | None]]:
        """Every run of the engine in order: its RunStart and its RunEnd (None while it runs, or
        when its process was killed). A journal written before runs were recorded: []."""
        try:
            rows = self._db.execute("SELECT run, program, started_utc, samples_planned, samples_done, end_record "
                                    "FROM runs ORDER BY run").fetchall()
        except sqlite3.OperationalError:  # a read-only view of a journal from before the runs table
            return []
        return [(RunStart(*row[:5]), None if row[5] is None else _run_end_from_json(row[5])) for row in rows]

    def suspensions(self) -> list[Suspension]:
        """Every suspension in order (a journal from before suspenders: [])."""
        try:
            rows = self._db.execute("SELECT run, reason, plan_index, started_utc, ended_utc, waited_s, end_kind "
                                    "FROM suspensions ORDER BY id").fetchall()
        except sqlite3.OperationalError:  # a read-only view of an older journal
            return []
        return [Suspension(*row[:6], None if row[6] is None else SuspensionEnd(row[6])) for row in rows]

    def last_run(self) -> tuple[RunStart | None, RunEnd | None]:
        """The last run's (RunStart, RunEnd), (None, None) before the first run."""
        runs = self.runs()
        return runs[-1] if runs else (None, None)

    def step_result(self, kind: str, plan_index: int | None = None) -> dict | None:
        """The result of the last step of ``kind`` (for plan sample ``plan_index``) that ended done;
        None if there is none."""
        row = self._db.execute("SELECT result FROM steps WHERE kind = ? AND plan_index IS ? AND status = 'done' "
                               "ORDER BY id DESC LIMIT 1", (kind, plan_index)).fetchone()
        return None if row is None else json.loads(row[0])

    def next_run(self) -> int:
        """The number of the next engine run of this session (1 for the first)."""
        return self._db.execute("SELECT MAX(COALESCE((SELECT MAX(run) FROM steps), 0), "
                                "COALESCE((SELECT MAX(run) FROM runs), 0)) + 1").fetchone()[0]

    # ----- writing ------------------------------------------------------------------------
    def set_label(self, label: SessionLabel) -> None:
        """Store (or replace: a resume's new notes) the session's label, in one transaction."""
        with self._transaction() as db:
            db.execute("INSERT OR REPLACE INTO meta VALUES ('label', ?)", (json.dumps(label.to_dict()),))

    def set_calibration(self, record: dict, step: tuple[int, dict] | None = None) -> None:
        """Store (or replace) the calibration record in one transaction; ``step`` (row, result): the
        step that saved it ends done in the same transaction."""
        with self._transaction() as db:
            db.execute("INSERT OR REPLACE INTO calibration VALUES (1, ?, ?)", (json.dumps(record), time.time()))
            _end_step(db, step)

    def commit_sample(self, record: SampleRecord, step: tuple[int, dict] | None = None) -> None:
        """Store one measured sample in ONE durable transaction; a plan index twice is refused.
        ``step`` (row, result): the step that commits it ends done in the same transaction."""
        self._commit_row("samples", "not_measured", _row_from_record(record), step)

    def commit_not_measured(self, record: NotMeasuredRecord, step: tuple[int, dict] | None = None,
                            message: str | None = None) -> None:
        """Store one plan sample the rig could not measure, as ``commit_sample`` stores a measured
        one (one durable transaction; a plan index already journaled, either way, is refused);
        ``message``: also a ``not_measured`` event with these words and the record as its data, in
        the same transaction."""
        event = None if message is None else (EventKind.NOT_MEASURED, message, record.to_dict())
        self._commit_row("not_measured", "samples", _row_from_not_measured(record), step, event)

    def _commit_row(self, table: str, other: str, row: dict, step, event=None) -> None:
        index = row["plan_index"]
        try:
            with self._transaction() as db:
                if db.execute(f"SELECT 1 FROM {other} WHERE plan_index = ?", (index,)).fetchone():
                    raise sqlite3.IntegrityError(f"plan sample {index} is in {other}")
                db.execute(f"INSERT INTO {table} ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                           tuple(row.values()))
                _end_step(db, step)
                if event is not None:
                    _insert_event(db, *event)
        except sqlite3.IntegrityError:
            raise JournalError(f"{self.path}: plan sample {index} is already in the journal") from None

    def add_event(self, kind: EventKind, message: str, axis: str | None = None, data: dict | None = None) -> None:
        """Record a device or session event (durably: a fault must outlive the process); ``message``
        is for people, ``data`` for readers."""
        with self._transaction() as db:
            _insert_event(db, kind, message, data, axis)

    def add_device_log(self, device_log) -> None:
        """Store the records ``device_log`` (``goniofrost.rig.device_log.DeviceLog``) collected since
        the last call as ``device`` events."""
        self.add_device_records(device_log.drain())

    def add_device_records(self, records) -> None:
        """Store ``logging.LogRecord``s of the drivers as ``device`` events."""
        for record in records:
            self.add_event(EventKind.DEVICE, record.getMessage(), data={"logger": record.name, "level": record.levelname})

    def start_run(self, start: RunStart) -> None:
        """Record that run ``start.run`` (``next_run()``) begins, durably."""
        with self._transaction() as db:
            db.execute("INSERT INTO runs (run, program, started_utc, samples_planned, samples_done) "
                       "VALUES (?, ?, ?, ?, ?)", (start.run, start.program, start.started_utc,
                                                  start.samples_planned, start.samples_done))

    def end_run(self, end: RunEnd) -> None:
        """Record how run ``end.run`` ended (durably); a run ends once."""
        with self._transaction() as db:
            cursor = db.execute("UPDATE runs SET status = ?, end_record = ? WHERE run = ? AND status IS NULL",
                                (RunStatus(end.status).value, json.dumps(asdict(end), default=str), end.run))
            if cursor.rowcount != 1:
                raise JournalError(f"{self.path}: run {end.run}: expected a started run without an end, found none")

    def start_suspension(self, run: int, reason, plan_index: int | None, message: str) -> int:
        """Record that run ``run`` is suspended for ``reason`` (a SuspendReason) and its event, durably;
        return the row id (for ``end_suspension``)."""
        with self._transaction() as db:
            cursor = db.execute("INSERT INTO suspensions (run, reason, plan_index, started_utc) VALUES (?, ?, ?, ?)",
                                (run, str(reason), plan_index, time.time()))
            _insert_event(db, EventKind.SUSPEND, message, {"reason": str(reason), "plan_index": plan_index,
                                                           "state": "suspended"})
        return cursor.lastrowid

    def end_suspension(self, row: int, end: SuspensionEnd, waited_s: float, message: str) -> None:
        """Record how suspension ``row`` ended after ``waited_s`` session-clock seconds, and its event."""
        with self._transaction() as db:
            db.execute("UPDATE suspensions SET ended_utc = ?, waited_s = ?, end_kind = ? WHERE id = ?",
                       (time.time(), float(waited_s), SuspensionEnd(end).value, row))
            _insert_event(db, EventKind.SUSPEND, message, {"end": SuspensionEnd(end).value, "waited_s": waited_s,
                                                           "state": "ended"})

    def start_step(self, run: int, kind: str, plan_index: int | None, detail: dict) -> int:
        """Record a plan step as running; return its row id (for ``end_step``)."""
        with self._transaction(durable=False) as db:
            cursor = db.execute("INSERT INTO steps (run, kind, plan_index, detail, status, result, started_utc) "
                                "VALUES (?, ?, ?, ?, 'running', '{}', ?)",
                                (run, kind, plan_index, json.dumps(detail, default=str), time.time()))
        return cursor.lastrowid

    def end_step(self, row: int, status: str, result: dict | None = None) -> None:
        """Record how step ``row`` ended (one of STEP_STATUSES but running) and a summary of its result."""
        if status not in STEP_STATUSES[1:]:
            raise JournalError(f"{self.path}: step status: expected one of {STEP_STATUSES[1:]}, found {status!r}")
        with self._transaction(durable=False) as db:
            _end_step(db, (row, result), status)

    def _transaction(self, durable: bool = True):
        return _Transaction(self._db, self.path, durable)


def _event_kind(value: str):
    try:
        return EventKind(value)
    except ValueError:
        return value


def _step_rows(cursor) -> list[dict]:
    names = [c[0] for c in cursor.description]
    rows = [dict(zip(names, row)) for row in cursor]
    for row in rows:
        row["detail"], row["result"] = json.loads(row["detail"]), json.loads(row["result"])
    return rows


def _run_end_from_json(text: str) -> RunEnd:
    values = json.loads(text)
    values["status"] = RunStatus(values["status"])
    values["stops"] = tuple(AxisStop(**s) for s in values.get("stops", ()))
    return RunEnd(**values)


def connect_read_only(path: Path) -> sqlite3.Connection:
    """A connection that cannot write the journal and creates no file beside it.

    While a capture writes the journal it is in WAL mode and its ``-wal`` file exists: ``mode=ro``
    shares the writer's WAL index, sees every committed transaction and never blocks the writer.
    Without a ``-wal`` file (the writer closed), ``mode=ro`` alone would create ``-wal`` and ``-shm``
    files, so the journal is then opened ``immutable``, which creates nothing.
    """
    path = Path(path).resolve()
    live_writer = path.with_name(path.name + "-wal").exists()
    query = "mode=ro" if live_writer else "mode=ro&immutable=1"
    return sqlite3.connect(f"{path.as_uri()}?{query}", uri=True, isolation_level=None, timeout=2.0,
                           check_same_thread=False)


def _insert_event(db: sqlite3.Connection, kind: EventKind, message: str, data: dict | None, axis: str | None = None):
    """Within a transaction: add an event (an unknown kind is refused here, not found missing by a reader)."""
    kind = EventKind(kind)
    db.execute("INSERT INTO events (t_utc, kind, axis, message, data) VALUES (?, ?, ?, ?, ?)",
               (time.time(), kind.value, axis, message, json.dumps(data or {}, default=str)))


def _end_step(db: sqlite3.Connection, step: tuple[int, dict | None] | None, status: str = "done") -> None:
    """Within a transaction: mark step ``(row, result)`` ended with ``status`` (nothing if None)."""
    if step is not None:
        row, result = step
        db.execute("UPDATE steps SET status = ?, result = ?, ended_utc = ? WHERE id = ?",
                   (status, json.dumps(result or {}, default=str), time.time(), row))


# SQLite primary result codes of a journal that cannot be written -> what a user reads after
# "PATH: cannot write: " (the engine turns them into its one-line message)
_DISK_ERRORS = {8: "the journal is read-only", 10: "input/output error (disk)",
                13: "no space left on the device", 14: "the journal file cannot be opened"}


def _disk_error(exc: sqlite3.Error, path: Path) -> OutputError | None:
    """An OutputError for an SQLite error that says the disk refused a write; None otherwise."""
    reason = _DISK_ERRORS.get(getattr(exc, "sqlite_errorcode", 0) & 0xFF)
    return None if reason is None else OutputError(path, reason)


class _Transaction:
    """BEGIN IMMEDIATE ... COMMIT (ROLLBACK on any exception); a full, read-only or failing disk
    becomes an ``OutputError`` naming the journal.

    ``durable=False``: this one commit does not wait for the disk (``synchronous=NORMAL``, WAL:
    safe against a killed process, not a power cut); the connection is FULL again afterwards.
    """

    def __init__(self, db: sqlite3.Connection, path: Path, durable: bool = True) -> None:
        self.db, self.path, self.durable = db, path, durable

    def __enter__(self) -> sqlite3.Connection:
        try:
            if not self.durable:
                self.db.execute("PRAGMA synchronous=NORMAL")
            self.db.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            self._restore()
            raise _disk_error(exc, self.path) or exc
        return self.db

    def __exit__(self, exc_type, exc, _tb) -> None:
        try:
            if exc_type is None:
                self.db.execute("COMMIT")
            else:
                self._rollback()
        except sqlite3.OperationalError as failed:
            self._rollback()
            raise _disk_error(failed, self.path) or failed
        finally:
            self._restore()
        if isinstance(exc, sqlite3.OperationalError) and _disk_error(exc, self.path) is not None:
            raise _disk_error(exc, self.path) from exc

    def _rollback(self) -> None:
        """Roll back if a transaction is still open (SQLite ends some on its own, e.g. a full disk)."""
        if self.db.in_transaction:
            try:
                self.db.execute("ROLLBACK")
            except sqlite3.Error:
                pass  # the original error matters more

    def _restore(self) -> None:
        if not self.durable:
            try:
                self.db.execute("PRAGMA synchronous=FULL")
            except sqlite3.Error:
                pass


def _connect(path: Path) -> sqlite3.Connection:
    path.parent.mkdir(parents=True, exist_ok=True)
    db = None
    try:
        db = sqlite3.connect(path, isolation_level=None)  # autocommit: transactions are explicit
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        db.executescript(_SCHEMA)
        _add_lower_limits(db)
    except sqlite3.DatabaseError as exc:
        if db is not None:
            db.close()  # not left open on a file the caller may remove
        disk = _disk_error(exc, path) if isinstance(exc, sqlite3.OperationalError) else None
        raise disk or JournalError(f"{path}: not a usable session journal ({exc})") from None
    return db


def _add_lower_limits(db: sqlite3.Connection) -> None:
    """A journal written before saturated samples were recorded has no lower limits: add them
    (0: its not-measured samples are all too dark, whose lower limit is 0)."""
    columns = {row[1] for row in db.execute("PRAGMA table_info(not_measured)")}
    for channel in "rgb":
        if f"lower_{channel}" not in columns:
            db.execute(f"ALTER TABLE not_measured ADD COLUMN lower_{channel} REAL NOT NULL DEFAULT 0")


_JSON_FIELDS = ("joints", "exposures_s", "raw_paths")


def _row_from_record(record: SampleRecord) -> dict:
    row = asdict(record)
    for i, channel in enumerate("rgb"):
        row[channel] = float(record.rgb[i])
        row[f"sigma_{channel}"] = float(record.sigma[i])
    del row["rgb"], row["sigma"]
    for name in _JSON_FIELDS:
        row[name] = json.dumps(row[name])
    return row


def _record_from_row(row: dict) -> SampleRecord:
    values = {f.name: row[f.name] for f in fields(SampleRecord) if f.name in row}
    values["rgb"] = (row["r"], row["g"], row["b"])
    values["sigma"] = (row["sigma_r"], row["sigma_g"], row["sigma_b"])
    values["joints"] = json.loads(row["joints"])
    values["exposures_s"] = tuple(json.loads(row["exposures_s"]))
    values["raw_paths"] = tuple(json.loads(row["raw_paths"]))
    return SampleRecord(**values)


def _row_from_not_measured(record: NotMeasuredRecord) -> dict:
    row = asdict(record)
    row["reason"] = str(record.reason)
    for i, channel in enumerate("rgb"):
        row[f"snr_{channel}"] = float(record.snr[i])
        row[f"upper_{channel}"] = float(record.upper_limit[i])
        row[f"lower_{channel}"] = float(record.lower_limit[i])
    del row["snr"], row["upper_limit"], row["lower_limit"]
    for name in _JSON_FIELDS:
        row[name] = json.dumps(row[name])
    return row


def _not_measured_from_row(row: dict) -> NotMeasuredRecord:
    values = {f.name: row[f.name] for f in fields(NotMeasuredRecord) if f.name in row}
    try:
        values["reason"] = NotMeasuredReason(row["reason"])
    except ValueError:   # a reason a later version wrote: kept as its value
        pass
    values["snr"] = (row["snr_r"], row["snr_g"], row["snr_b"])
    values["upper_limit"] = (row["upper_r"], row["upper_g"], row["upper_b"])
    # a read-only view of a journal from before the lower limits: too dark only, so 0
    values["lower_limit"] = tuple(row.get(f"lower_{channel}", 0.0) for channel in "rgb")
    values["joints"] = json.loads(row["joints"])
    values["exposures_s"] = tuple(json.loads(row["exposures_s"]))
    values["raw_paths"] = tuple(json.loads(row["raw_paths"]))
    return NotMeasuredRecord(**values)


class SamplesCsv:
    """``samples.csv`` of a session, one line per sample, in the format of
    ``goniofrost.frost.samples_file`` (``SESSION_COLUMNS``, and ``batch``: 1-based, the plan's batch
    of the sample, when ``batch_ends`` are given, a capture with a target error).
    """

    def __init__(self, path, batch_ends=()) -> None:
        self.path = Path(path)
        self.batch_ends = tuple(batch_ends)

    def rewrite(self, records) -> None:
        """Replace the file atomically with exactly ``records`` (the journal is the truth)."""
        header = samples_file.header(batched=bool(self.batch_ends))
        write_text_atomic(self.path, header + "\n" + "".join(self._line(r) + "\n" for r in records))

    def _line(self, record: SampleRecord) -> str:
        batch = None
        if self.batch_ends:
            from goniofrost.capture.target import batch_of
            batch = batch_of(self.batch_ends, record.plan_index)
        return samples_file.session_row((record.theta_h_deg, record.theta_d_deg, record.phi_d_deg), record.rgb,
                                        record.sigma, record.snr, record.plan_index, batch)

    def append(self, record: SampleRecord) -> None:
        """Append one sample's line, flushed and fsynced before returning (OutputError when the disk
        refuses: the journal has the sample, and a resume rewrites this file from it)."""
        with output_errors(self.path), open(self.path, "a") as handle:
            handle.write(self._line(record) + "\n")
            handle.flush()
            os.fsync(handle.fileno())
