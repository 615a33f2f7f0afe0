"""One program drives a rig at a time: an exclusive lock per rig, beside the session lock.

``rig_lock(rig_name, program)`` holds an ``flock`` on ``LOCK_DIR/rig-NAME.lock`` from before the
rig's devices are connected until after they are released (``goniofrost.rig.hardware``
takes it for every program that connects a rig: capture, align, the console). The kernel releases
it when the holder exits in any way (kill -9 included), so a stale lock cannot exist. The file
holds the holder as JSON (``RigHolder``: PID, program, rig, start time); ``rig_holder(name)``
reads it without touching the lock.

Another process asks the holder to stop with ``request_stop(rig_name)``: it writes the request
file ``LOCK_DIR/rig-NAME.stop`` (who asks) and sends the holder SIGTERM. The holder's engine turns
the signal into an operator's stop at once (``goniofrost.capture.signals``), and also checks the
request file between steps (a holder whose engine runs off the main thread gets no signal): the
run ends ``stopped_by_operator`` with its own per-axis stop report, and ``--resume`` continues it.

``LOCK_DIR`` is ``$GONIOFROST_LOCK_DIR``, else ``$XDG_RUNTIME_DIR/goniofrost``, else
``TMPDIR/goniofrost-UID``: every program of one user on one computer sees the same locks.
"""
from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import tempfile
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from goniofrost.core.atomic_file import output_errors, write_text_atomic
from goniofrost.core.errors import GoniofrostError

LOCK_DIR_ENV = "GONIOFROST_LOCK_DIR"


class RigInUseError(GoniofrostError):
    """Another program holds the rig's lock."""


@dataclass(frozen=True)
class RigHolder:
    """The program that holds a rig: its PID, its name (``capture``, ``align``, ``rig move``...),
    the rig's name and the Unix time it took the lock."""

    pid: int
    program: str
    rig: str
    started_utc: float


def lock_dir() -> Path:
    """Where the rig locks are (module doc)."""
    if os.environ.get(LOCK_DIR_ENV):
        return Path(os.environ[LOCK_DIR_ENV])
    if os.environ.get("XDG_RUNTIME_DIR"):
        return Path(os.environ["XDG_RUNTIME_DIR"]) / "goniofrost"
    return Path(tempfile.gettempdir()) / f"goniofrost-{os.getuid()}"


def lock_path(rig_name: str) -> Path:
    """The lock file of the rig named ``rig_name`` (characters other than letters, digits, '.',
    '_' and '-' become '_')."""
    return lock_dir() / f"rig-{re.sub(r'[^A-Za-z0-9._-]', '_', rig_name) or '_'}.lock"


def stop_path(rig_name: str) -> Path:
    return lock_path(rig_name).with_suffix(".stop")


class RigLock:
    """The held lock of one rig (``rig_lock`` yields it); ``stop_request()`` says whether another
    process asked this holder to stop."""

    def __init__(self, holder: RigHolder) -> None:
        self.holder = holder
        self._stop = stop_path(holder.rig)

    def stop_request(self) -> str | None:
        """'a stop request from process N' when one was made since the lock was taken, else None."""
        try:
            asked = json.loads(self._stop.read_text())
        except (OSError, ValueError):
            return None
        return f"a stop request from process {asked.get('pid', '?')}"


@contextmanager
def rig_lock(rig_name: str, program: str):
    """Hold the lock of rig ``rig_name`` for ``program`` until the block ends; yield the RigLock.

    Raises ``RigInUseError`` at once (no waiting) naming the holder when another program holds it.
    """
    path = lock_path(rig_name)
    with output_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RigInUseError(_in_use(rig_name, _read_holder(path))) from None
        holder = RigHolder(os.getpid(), program, rig_name, time.time())
        stop_path(rig_name).unlink(missing_ok=True)  # a request made to an earlier holder is not ours
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(asdict(holder)).encode(), 0)
        try:
            yield RigLock(holder)
        finally:
            stop_path(rig_name).unlink(missing_ok=True)
    finally:
        os.close(fd)  # releases the lock


def rig_holder(rig_name: str) -> RigHolder | None:
    """The program that holds rig ``rig_name`` now, or None (read from /proc/locks: the lock itself
    is never touched, so a program taking it at this moment is not refused)."""
    path = lock_path(rig_name)
    if not _flock_held(path):
        return None
    return _read_holder(path)


def check_free(rig_name: str) -> None:
    """Raise ``RigInUseError`` naming the holder when another program holds rig ``rig_name`` now: a
    program with minutes of work before it connects (the demo's training) asks first. Only a
    courtesy: the lock itself is taken when the rig is connected."""
    if _flock_held(lock_path(rig_name)):
        raise RigInUseError(_in_use(rig_name, _read_holder(lock_path(rig_name))))


def request_stop(rig_name: str) -> RigHolder | None:
    """Ask the program that holds rig ``rig_name`` to stop (module doc); return it, or None when no
    program holds the rig (then nothing was sent). Returns at once: the holder's own report (its
    terminal, its journal's RunEnd) says how each axis took the stop."""
    holder = rig_holder(rig_name)
    if holder is None:
        return None
    write_text_atomic(stop_path(rig_name), json.dumps({"pid": os.getpid(), "t_utc": time.time()}))
    try:
        os.kill(holder.pid, signal.SIGTERM)
    except ProcessLookupError:  # it ended in between: nothing holds the rig any more
        return None
    return holder


def _read_holder(path: Path) -> RigHolder | None:
    try:
        return RigHolder(**json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        return None


def _in_use(rig_name: str, holder: RigHolder | None) -> str:
    who = f"{holder.program} (process {holder.pid})" if holder else "another program"
    return (f"rig {rig_name!r} is in use by {who}: one program drives a rig at a time; wait for it to "
            f"finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)")


def _flock_held(path: Path) -> bool:
    """Whether some process holds the rig lock file's flock (False without the file)."""
    return bool(flock_held(path))


def flock_held(lock) -> bool | None:
    """Whether some process holds the flock on the file ``lock`` (a session's or a rig's lock), read
    from /proc/locks without touching the lock itself (taking it, even shared and for an instant,
    could refuse a program that starts at that moment). None where that cannot be told (no lock
    file; no /proc/locks: not Linux)."""
    holders = flock_holders(lock)
    return None if holders is None else bool(holders)


def flock_holders(lock) -> list[str] | None:
    """The holders /proc/locks gives for the flocks on the file ``lock``, each as its PID column
    reads (empty: none held); None where that cannot be told (no lock file; no /proc/locks: not Linux)."""
    try:
        st = os.stat(lock)
        table = Path("/proc/locks").read_text()
    except OSError:
        return None
    device = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    # "1: FLOCK  ADVISORY  WRITE 10327 fe:00:9978325 0 EOF": kind, mode, access, PID, device:inode
    rows = [line.split() for line in table.splitlines()]
    return [row[4] for row in rows if row[1:2] == ["FLOCK"] and device in row]

