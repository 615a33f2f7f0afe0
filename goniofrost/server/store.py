"""The server's SQLite file under its root (``ROOT/serve.sqlite``): the queue and the actions.

``queue``: one row per entry (plan file relative to the root, material, sample_id, operator, note,
target_error, confidence), its state (``pending``, ``running``, ``done``, ``failed``, ``stopped``,
``removed``) and its session folder; ``position`` orders it (``move`` reorders the pending ones).
An entry ``running`` when the server died is run again with ``resume`` on the next start: the
capture journal resumes it without losing or repeating a sample.
``actions``: every control request, with who asked (``operator`` of the request, and its peer
address) and when (Unix seconds). SQLite in WAL mode; every write is its own transaction.
"""
from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

DB_FILE = "serve.sqlite"
ENTRY_FIELDS = ("plan", "material", "sample_id", "operator", "note", "target_error", "confidence")
SCHEMA = """
CREATE TABLE IF NOT EXISTS queue (
  id INTEGER PRIMARY KEY AUTOINCREMENT, plan TEXT NOT NULL, material TEXT, sample_id TEXT NOT NULL,
  operator TEXT NOT NULL, note TEXT NOT NULL, target_error REAL, confidence REAL NOT NULL,
  state TEXT NOT NULL, session TEXT, added_utc REAL NOT NULL, started_utc REAL, ended_utc REAL,
  result TEXT, position INTEGER);
CREATE TABLE IF NOT EXISTS actions (
  id INTEGER PRIMARY KEY AUTOINCREMENT, t_utc REAL NOT NULL, who TEXT NOT NULL, peer TEXT NOT NULL,
  action TEXT NOT NULL, detail TEXT NOT NULL);
"""


class Store:
    """The queue and the action journal of one server root (module doc); thread-safe."""

    def __init__(self, root: Path) -> None:
        self.path = Path(root) / DB_FILE
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._lock = threading.Lock()
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.executescript(SCHEMA)
            columns = [row["name"] for row in self._db.execute("PRAGMA table_info(queue)")]
            if "position" not in columns:  # a root served before entries could be reordered
                self._db.execute("ALTER TABLE queue ADD COLUMN position INTEGER")
            self._db.execute("UPDATE queue SET position = id WHERE position IS NULL")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _run(self, sql: str, args=()) -> list[dict]:
        with self._lock:
            return [dict(row) for row in self._db.execute(sql, args).fetchall()]

    # ----- the queue -------------------------------------------------------------------------
    def add(self, entry: dict) -> dict:
        """Queue a checked entry (ENTRY_FIELDS) as pending; return its row."""
        with self._lock:
            cur = self._db.execute(
                f"INSERT INTO queue ({', '.join(ENTRY_FIELDS)}, state, added_utc) VALUES "
                f"({', '.join('?' * len(ENTRY_FIELDS))}, 'pending', ?)",
                [entry[k] for k in ENTRY_FIELDS] + [time.time()])
            new = cur.lastrowid
            self._db.execute("UPDATE queue SET position = (SELECT COALESCE(MAX(position), 0) + 1 FROM queue) "
                             "WHERE id = ?", (new,))
        return self.entry(new)

    def entry(self, entry_id: int) -> dict | None:
        rows = self._run("SELECT * FROM queue WHERE id = ?", (entry_id,))
        return rows[0] if rows else None

    def entries(self) -> list[dict]:
        """Every entry not removed, in queue order."""
        return self._run("SELECT * FROM queue WHERE state != 'removed' ORDER BY position, id")

    def next_entry(self) -> dict | None:
        """The entry to run: one left running by a server that died first, else the oldest pending."""
        rows = self._run("SELECT * FROM queue WHERE state IN ('running', 'pending') "
                         "ORDER BY state = 'running' DESC, position, id LIMIT 1")
        return rows[0] if rows else None

    def remove(self, entry_id: int) -> bool:
        """Remove a pending entry; False when it is not pending (running, done, or unknown)."""
        with self._lock:
            cur = self._db.execute("UPDATE queue SET state = 'removed' WHERE id = ? AND state = 'pending'",
                                   (entry_id,))
            return cur.rowcount == 1

    def move(self, entry_id: int, before: int | None) -> list[int] | None:
        """Put pending entry ``entry_id`` just before pending entry ``before`` (None: last); the
        pending entries swap positions among themselves only. Return the pending ids in their new
        order, or None (nothing changed) when either is not a pending entry."""
        with self._lock:
            rows = self._db.execute("SELECT id, position FROM queue WHERE state = 'pending' "
                                    "ORDER BY position, id").fetchall()
            order = [row["id"] for row in rows]
            if entry_id not in order or (before is not None and (before not in order or before == entry_id)):
                return None
            order.remove(entry_id)
            order.insert(order.index(before) if before is not None else len(order), entry_id)
            self._db.execute("BEGIN")
            for moved, row in zip(order, rows):
                self._db.execute("UPDATE queue SET position = ? WHERE id = ?", (row["position"], moved))
            self._db.execute("COMMIT")
            return order

    def started(self, entry_id: int, session: str) -> None:
        self._run("UPDATE queue SET state = 'running', session = ?, started_utc = COALESCE(started_utc, ?) "
                  "WHERE id = ?", (session, time.time(), entry_id))

    def ended(self, entry_id: int, state: str, result: dict) -> None:
        self._run("UPDATE queue SET state = ?, ended_utc = ?, result = ? WHERE id = ?",
                  (state, time.time(), json.dumps(result), entry_id))

    # ----- the actions -------------------------------------------------------------------------
    def journal(self, who: str, peer: str, action: str, detail: dict | None = None) -> None:
        """Record one control action (who asked, from where, what, when)."""
        self._run("INSERT INTO actions (t_utc, who, peer, action, detail) VALUES (?, ?, ?, ?, ?)",
                  (time.time(), who, peer, action, json.dumps(detail or {}, sort_keys=True)))

    def actions(self) -> list[dict]:
        return self._run("SELECT * FROM actions ORDER BY id")
