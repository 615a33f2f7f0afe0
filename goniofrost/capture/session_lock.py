"""One process per session: an exclusive OS file lock on ``DIR/session.lock`` for the whole run.

Two captures of one session would drive the same motors and write the same files. The lock is an
``flock`` on an open file, so the kernel releases it when the holder exits in any way (kill -9
included): a stale lock cannot exist. The file holds the holder's PID, for the message only.
"""
from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from pathlib import Path

from goniofrost.core.atomic_file import output_errors
from goniofrost.core.errors import GoniofrostError

LOCK_FILE = "session.lock"


class SessionInUseError(GoniofrostError):
    """Another process holds the session's lock."""


@contextmanager
def session_lock(session_dir: Path):
    """Create ``session_dir`` if needed and hold its lock until the block ends.

    Raises ``SessionInUseError`` at once (no waiting) when another process holds it, and
    ``OutputError`` when the folder cannot be made (a file in the way, read-only, ...).
    """
    session_dir = Path(session_dir)
    path = session_dir / LOCK_FILE
    with output_errors(session_dir):
        session_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        _acquire(fd, session_dir)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        os.close(fd)   # releases the lock


def _acquire(fd: int, session_dir: Path) -> None:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        raise SessionInUseError(f"session {session_dir} is in use by process {holder}; wait for it to finish "
                                f"or stop it (Ctrl-C) before starting another capture on it") from None


def flock_held(lock) -> bool | None:
    """Whether some process holds the flock on the file ``lock`` (a session's or a rig's lock), read
    from /proc/locks without touching the lock itself (taking it, even shared and for an instant,
    could refuse a program that starts at that moment). None where that cannot be told (no lock
    file; no /proc/locks: not Linux)."""
    try:
        st = os.stat(lock)
        table = Path("/proc/locks").read_text()
    except OSError:
        return None
    device = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    return any(line.split()[1:2] == ["FLOCK"] and device in line.split() for line in table.splitlines())
