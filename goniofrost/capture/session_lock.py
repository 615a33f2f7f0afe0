"""One process per session: an exclusive OS file lock on ``DIR/session.lock`` for the whole run.

Two captures of one session would drive the same motors and write the same files. The lock is an
``flock`` on an open file, so the kernel releases it when the holder exits in any way (kill -9
included): a stale lock cannot exist. The file holds the holder's PID, for the message only.
"""
from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from goniofrost.core.atomic_file import output_errors
from goniofrost.core.errors import GoniofrostError
from goniofrost.rig.lock import flock_holders

LOCK_FILE = "session.lock"


class SessionInUseError(GoniofrostError):
    """Another process holds the session's lock."""


@dataclass
class HeldLock:
    """The held lock of a session: ``claim`` writes this process's PID once the run is accepted."""

    path: Path
    fd: int
    created: bool   # this run made the file: a refused run removes it

    def claim(self) -> None:
        """Record this process as the holder (what a second capture's refusal names)."""
        with output_errors(self.path):
            os.ftruncate(self.fd, 0)
            os.pwrite(self.fd, f"{os.getpid()}\n".encode(), 0)


@contextmanager
def session_lock(session_dir: Path):
    """Create ``session_dir`` if needed and hold its lock until the block ends; yield a HeldLock.

    The lock file is not written until ``claim``: a run refused under the lock (an existing
    session without --resume) must leave the session's files as they were.
    Raises ``SessionInUseError`` at once (no waiting) when another process holds it, and
    ``OutputError`` when the folder cannot be made (a file in the way, read-only, ...).
    """
    session_dir = Path(session_dir)
    path = session_dir / LOCK_FILE
    with output_errors(session_dir):
        session_dir.mkdir(parents=True, exist_ok=True)
        fd, created = _open(path)
    try:
        _acquire(fd, session_dir)
        yield HeldLock(path, fd, created)
    finally:
        os.close(fd)   # releases the lock


def _open(path: Path) -> tuple[int, bool]:
    """(descriptor, whether this call created the file) of the lock file ``path``."""
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
    except FileExistsError:
        return os.open(path, os.O_RDWR), False


def _acquire(fd: int, session_dir: Path) -> None:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        # The kernel's word first: the file names the holder only once it claimed the session
        # (``HeldLock.claim``); before that it still holds the previous run's PID.
        holders = flock_holders(session_dir / LOCK_FILE)
        holder = holders[0] if holders else os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        raise SessionInUseError(f"session {session_dir} is in use by process {holder}; wait for it to finish "
                                f"or stop it (Ctrl-C) before starting another capture on it") from None
