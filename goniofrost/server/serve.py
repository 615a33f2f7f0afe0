"""``goniofrost serve``: hold a rig's devices and serve the instrument until Ctrl-C or SIGTERM.

Order: bind the address (its URL goes into the lock), take the device lock for the server's
lifetime (publishing the URL and the token file), open every device once, start the instrument
thread (a queue entry left running by a server that died is resumed first), then serve. The token
is random per start, in ``ROOT/serve.token`` (mode 0600: this user only) and printed as a URL the
way Jupyter does.
"""
from __future__ import annotations

import os
import re
import secrets
import signal
import sys
import threading
from pathlib import Path

from goniofrost.core.errors import GoniofrostError

TOKEN_FILE = "serve.token"
SESSIONS = "sessions"
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def write_token(path: Path) -> str:
    """A new random token, written to ``path`` readable by this user only (a file left by an
    earlier start is replaced, never reused)."""
    token = secrets.token_urlsafe(32)
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(token + "\n")
    return token


def session_name(entry: dict) -> str:
    """The session folder of a queue entry: its id and sample id (as a file name)."""
    return f"{entry['id']:04d}-{re.sub(r'[^A-Za-z0-9._-]', '_', entry['sample_id'])[:60]}"


def entry_runner(root: Path, rig_path: Path, store, speedup: float | None, compare=None):
    """``run(entry, devices)``: capture (or resume) the queue entry's session on the held devices;
    ``compare(material)``: what an entry's simulated material is compared with in its report (the
    command line's ``GroundTruth``; None: no comparison)."""
    def run(entry: dict, devices) -> dict:
        from goniofrost.capture.lab import session_label
        from goniofrost.capture.inputs import inputs_on
        from goniofrost.capture.options import SessionOptions, StopRule
        from goniofrost.capture.runner import JOURNAL_FILE, capture
        from goniofrost.datasets import shown_material
        from goniofrost.rig.file import load_checked_rig
        from goniofrost.rig.hardware import SimOptions

        session = root / SESSIONS / session_name(entry)
        store.started(entry["id"], str(session.relative_to(root)))
        rig = load_checked_rig(rig_path)
        label = session_label(rig, entry["operator"] or None, entry["sample_id"],
                              [entry["note"]] if entry["note"] else (), source="queue entry")
        material = shown_material(entry["material"], "material") if entry["material"] else None
        options = SessionOptions(resume=(session / JOURNAL_FILE).exists(), progress=False, label=label,
                                 rerun="POST /api/resume",
                                 compare=None if material is None or compare is None else compare(material))
        outcome = capture(inputs_on(rig, root / entry["plan"]), session, devices=devices,
                          sim=SimOptions(material=material, speedup=speedup),
                          stop=StopRule(entry["target_error"], entry["confidence"]), options=options)
        return {"session": str(session.relative_to(root)), "summary": outcome.summary}
    return run


def serve(rig_path, root, *, host: str = "127.0.0.1", port: int = 8765, speedup: float | None = None,
          say=print, compare=None) -> int:
    """Run the server until SIGINT or SIGTERM (module doc); return the exit status. A refused start
    (the rig or the root in use, the address taken) leaves the root as it was. ``compare``: as for
    ``entry_runner``."""
    from goniofrost.monitor.server import AppServer
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.rig.lock import rig_lock
    from goniofrost.rig.simulated import rig_devices
    from goniofrost.server.api import Api, instrument_app
    from goniofrost.server.instrument import Instrument
    from goniofrost.server.store import Store

    rig_path, root = Path(rig_path).resolve(), Path(root).resolve()
    rig = load_checked_rig(rig_path)
    if speedup is not None and not rig.simulated:
        raise GoniofrostError("--speedup: only a simulated rig's clock can be sped up")
    if not root.is_dir():
        raise GoniofrostError(f"--root: {root} is not a folder (make it, and put the plan files in it)")
    if host not in LOOPBACK:
        say(f"goniofrost serve: WARNING: listening on {host}: anyone on that network with the token can move "
            f"the rig; use it only on a trusted network", file=sys.stderr, flush=True)
    built = {}

    async def app(scope, receive, send):  # bound first (the URL goes into the lock), built once the rig is held
        await built["app"](scope, receive, send)
    server = AppServer(app, host, port)
    token_file = root / TOKEN_FILE
    try:
        with root_lock(root), rig_lock(rig, "serve", url=server.url, token_file=str(token_file)) as lock:
            token = write_token(token_file)
            (root / SESSIONS).mkdir(exist_ok=True)
            store = Store(root)
            try:
                with rig_devices(rig, speedup=speedup) as hardware:
                    instrument = Instrument(rig, hardware, lock, store, entry_runner(root, rig_path, store, speedup, compare))
                    api = Api(instrument, store, root, rig_path, token, server.url.rstrip("/"))
                    built["app"] = instrument_app(api, root / SESSIONS, host)
                    instrument.start()
                    try:
                        with server:
                            say(f"goniofrost serve: {rig.name} held; serving on {server.url}?token={token}", flush=True)
                            say(f"  token in {token_file}; Ctrl-C stops", flush=True)
                            wait_for_signal()
                    finally:
                        instrument.close()
            finally:
                store.close()
                token_file.unlink(missing_ok=True)
    finally:
        server.socket.close()
    return 0


def root_lock(root: Path):
    """Hold ROOT/serve.lock: one server per root (its queue and token are the root's)."""
    import fcntl
    from contextlib import contextmanager

    @contextmanager
    def held():
        path = root / "serve.lock"
        existed = path.exists()
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise GoniofrostError(f"--root: {root} is served by another goniofrost serve "
                                      f"(process {os.pread(fd, 32, 0).decode(errors='replace').strip() or '?'}); "
                                      f"one server per root") from None
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, str(os.getpid()).encode(), 0)
                yield
            except GoniofrostError:
                if not existed:  # a refused start leaves the root as it was
                    path.unlink(missing_ok=True)
                raise
        finally:
            os.close(fd)
    return held()


def wait_for_signal() -> None:
    """Block until SIGINT or SIGTERM."""
    done = threading.Event()
    previous = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not done.wait(1.0):
            pass
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
