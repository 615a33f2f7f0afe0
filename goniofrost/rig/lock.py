"""One program, of any user, drives a device at a time: locks keyed by the devices a rig file names.

``device_keys(rig)`` names the devices: ``serial:PATH`` (resolved), ``tcp:HOST:PORT/UNIT``, and
``simulated:/abs/rig.yaml`` for a simulated rig. ``rig_lock(rig, program)`` holds an ``flock`` on
``LOCK_DIR/dev-HASH.lock`` per key while the devices are connected (``goniofrost.rig.hardware``);
the kernel releases it however the holder exits. Each file names the holder as JSON
(``RigHolder``: PID, user, program, rig, keys, a server's URL and token file), read by
``rig_holder(rig)``. ``request_stop(rig)`` writes the holder's stop file and sends it SIGTERM when
it may. ``LOCK_DIR`` is ``$GONIOFROST_LOCK_DIR``, else ``/tmp/goniofrost-locks`` (mode 1777).
docs/explanations/rig-lock.md says why.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import pwd
import signal
import stat
import time
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from goniofrost.core.errors import GoniofrostError

LOCK_DIR_ENV = "GONIOFROST_LOCK_DIR"
SHARED_LOCK_DIR = Path("/tmp/goniofrost-locks")
SERIAL_PROTOCOLS = ("dynamixel", "smc100", "modbus-rtu")


class RigInUseError(GoniofrostError):
    """Another program holds a device of the rig."""


@dataclass(frozen=True)
class RigHolder:
    """The program that holds a rig's devices: its PID and user, its name (``capture``, ``serve``,
    ``rig move``...), the rig's name, the Unix time it took the lock, the device keys it holds,
    and for a server the URL of its API and the file holding its token (readable by its user only)."""

    pid: int
    program: str
    rig: str
    started_utc: float
    user: str = "?"
    uid: int = -1
    keys: tuple = ()
    url: str | None = None
    token_file: str | None = None

    def who(self) -> str:
        """e.g. "capture (process 4242 of alice)"."""
        return f"{self.program} (process {self.pid} of {self.user})"


def lock_dir() -> Path:
    """Where the device locks are (module doc)."""
    return Path(os.environ.get(LOCK_DIR_ENV) or SHARED_LOCK_DIR)


def device_keys(rig) -> list[str]:
    """The sorted keys of the devices ``rig`` (a loaded ``planner.rig.Rig``) names (module doc)."""
    if rig.simulated:
        return [f"simulated:{Path(rig.source).resolve()}"]
    sections = {name: axis.driver for name, axis in rig.axes.items()}
    keys = {_endpoint(section) for section in sections.values()}
    lamp = (rig.lamp or {}).get("driver")
    if lamp:  # a lamp on an axis's device is that device; its own port is another
        keys.add(_endpoint(sections[lamp["device"]]) if "device" in lamp else _endpoint(lamp))
    return sorted(keys)


def _endpoint(section) -> str:
    if section["protocol"] in SERIAL_PROTOCOLS or "host" not in section:
        return f"serial:{os.path.realpath(section['port'])}"
    unit = section.get("device_id", 1)
    return f"tcp:{str(section['host']).lower()}:{section['port']}/{unit}"


def lock_path(key: str) -> Path:
    """The lock file of the device key ``key``."""
    return lock_dir() / f"dev-{hashlib.sha256(key.encode()).hexdigest()[:20]}.lock"


def stop_path(key: str) -> Path:
    return lock_path(key).with_suffix(".stop")


class RigLock:
    """The held lock of one rig (``rig_lock`` yields it); ``stop_request()`` says whether another
    process asked this holder to stop."""

    def __init__(self, holder: RigHolder) -> None:
        self.holder = holder
        self._stop = stop_path(holder.keys[0])

    def stop_request(self) -> str | None:
        """'a stop request from process N' when one was made to this holder, else None."""
        try:
            asked = json.loads(self._stop.read_text())
        except (OSError, ValueError):
            return None
        if asked.get("holder_pid") != self.holder.pid or asked.get("holder_started") != self.holder.started_utc:
            return None
        return f"a stop request from process {asked.get('pid', '?')}"


@contextmanager
def rig_lock(rig, program: str, *, url: str | None = None, token_file: str | None = None):
    """Hold the locks of every device of ``rig`` for ``program`` until the block ends; yield the
    RigLock. ``url``, ``token_file``: a server's, published to whoever reads the holder.

    Raises ``RigInUseError`` at once (no waiting) naming the holder when another program holds one
    of the devices; then none is held.
    """
    keys = device_keys(rig)
    holder = RigHolder(os.getpid(), program, rig.name, time.time(), _user(os.getuid()), os.getuid(),
                       tuple(keys), url, token_file)
    with ExitStack() as held:
        fds = []
        for key in keys:
            fd = _open_lock(lock_path(key))
            held.callback(os.close, fd)  # closing releases the lock
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise RigInUseError(_in_use(rig.name, _read_holder(lock_path(key)))) from None
            fds.append(fd)
        text = json.dumps(asdict(holder)).encode()
        for fd in fds:
            os.ftruncate(fd, 0)
            os.pwrite(fd, text, 0)
        yield RigLock(holder)


def _open_lock(path: Path) -> int:
    """Open (create: mode 0666 whatever the umask) a lock file in the shared folder."""
    shared_dir(path.parent)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    except OSError as exc:
        raise GoniofrostError(f"{path}: cannot open the device lock: {exc.strerror}") from None
    if os.fstat(fd).st_uid == os.getuid():
        os.fchmod(fd, 0o666)
    return fd


def shared_dir(path: Path) -> None:
    """Create ``path`` as a world-writable sticky folder (1777), or check that it is one: a folder
    others may write but that is not sticky would let any user remove the locks."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        st = path.lstat()
        if st.st_uid == os.getuid() and stat.S_IMODE(st.st_mode) != 0o1777:
            os.chmod(path, 0o1777)
            st = path.lstat()
    except OSError as exc:
        raise GoniofrostError(f"{path}: cannot make the shared folder of device locks: {exc.strerror}") from None
    if not stat.S_ISDIR(st.st_mode) or stat.S_IMODE(st.st_mode) != 0o1777:
        raise GoniofrostError(f"{path}: the device locks' folder must be a directory of mode 1777 (sticky, "
                              f"writable by all), found mode {stat.S_IMODE(st.st_mode):o}")


def rig_holder(rig) -> RigHolder | None:
    """The program that holds a device of ``rig`` now, or None (read from /proc/locks: the lock
    itself is never touched, so a program taking it at this moment is not refused)."""
    for key in device_keys(rig):
        if flock_held(lock_path(key)):
            return _read_holder(lock_path(key))
    return None


def check_free(rig) -> None:
    """Raise ``RigInUseError`` naming the holder when another program holds a device of ``rig``
    now: a program with minutes of work before it connects (the demo's training) asks first. Only
    a courtesy: the lock itself is taken when the rig is connected."""
    for key in device_keys(rig):
        if flock_held(lock_path(key)):
            raise RigInUseError(_in_use(rig.name, _read_holder(lock_path(key))))


def request_stop(rig) -> RigHolder | None:
    """Ask the program that holds ``rig``'s devices to stop (module doc); return it, or None when
    no program holds them (then nothing was sent). Raises ``RigInUseError`` naming the holder when
    it is another user's process, which this one may not signal. Returns at once: the holder's
    own report (its terminal, its journal's RunEnd) says how each axis took the stop."""
    holder = rig_holder(rig)
    if holder is None:
        return None
    if holder.keys:
        request = {"pid": os.getpid(), "holder_pid": holder.pid, "holder_started": holder.started_utc,
                   "t_utc": time.time()}
        fd = _open_lock(stop_path(holder.keys[0]))
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(request).encode(), 0)
        finally:
            os.close(fd)
    try:
        os.kill(holder.pid, signal.SIGTERM)
    except ProcessLookupError:  # it ended in between: nothing holds the rig any more
        return None
    except PermissionError:
        raise RigInUseError(f"rig {rig.name!r} is held by {holder.who()}: another user's process, which only "
                            f"that user (or root) may stop; it was asked through its stop file") from None
    return holder


def _user(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def _read_holder(path: Path) -> RigHolder | None:
    try:
        data = json.loads(path.read_text())
        data["keys"] = tuple(data.get("keys", ()))
        return RigHolder(**data)
    except (OSError, ValueError, TypeError):
        return None


def _in_use(rig_name: str, holder: RigHolder | None) -> str:
    who = holder.who() if holder else "another program"
    same = f" (its rig {holder.rig!r})" if holder and holder.rig != rig_name else ""
    return (f"rig {rig_name!r} is in use by {who}{same}: one program drives a device at a time; wait for it to "
            f"finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)")


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
