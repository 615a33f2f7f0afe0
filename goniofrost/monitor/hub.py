"""What the monitor serves of each session: its page state, re-read when the journal changes, and
its latest pictures, shared by every open page.

``Site`` is one session (a ``StateHub`` and two ``PictureCache``); ``Sites`` the sessions one app
serves. Worker threads read the hub; the event loop's streams wait on it (``wait_newer``). The
journal is polled (a ``stat`` of four files every POLL_S) only while a page is connected; pictures
are made one at a time, and after one took t seconds the next of its kind waits t / PICTURE_DUTY
(within PICTURE_MIN_GAP_S and PICTURE_MAX_GAP_S).
"""
from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from pathlib import Path

from goniofrost.core.errors import GoniofrostError
from goniofrost.monitor.images import PictureUnavailable
from goniofrost.monitor.session_view import REPORT_FILE, journal_path, read_session
from goniofrost.monitor.status import page_state

log = logging.getLogger(__name__)

POLL_S = 0.25              # journal change check while a page is connected
TIME_REFRESH_S = 2.0       # re-derive the state this often even unchanged (stall detection)
PICTURE_DUTY = 0.03        # pictures take at most ~3 % of one core
PICTURE_MIN_GAP_S = 0.5
PICTURE_MAX_GAP_S = 5.0    # ... but never older than this (a first picture also loads the model)


class StateHub:
    """The session's current page state, re-read when the journal changes, shared by every page.

    ``clients`` maps each open event stream to the state version it was last sent.
    """

    def __init__(self, session_dir, attached: bool) -> None:
        self.session_dir, self.attached = Path(session_dir), attached
        self.ended_message: str | None = None
        self.view = read_session(self.session_dir)
        self.rig = None
        self.version, self.closed, self.clients = 0, False, {}
        self._body, self._signature, self._read_at = "{}", None, 0.0
        self._lock, self._read_lock = threading.Lock(), threading.Lock()
        self._waiters: set = set()   # (event loop, asyncio.Event) of the streams waiting for a change

    def refresh(self, force: bool = False) -> None:
        """Read the session again if its files changed (or TIME_REFRESH_S passed)."""
        with self._read_lock:
            signature, now = self._signature_now(), time.time()
            if not force and signature == self._signature and now - self._read_at < TIME_REFRESH_S:
                return
            view = read_session(self.session_dir)
            rig = self._rig(view)
            state = page_state(view, now, attached=self.attached, ended_message=self.ended_message, rig=rig)
            body = json.dumps(state, sort_keys=True, allow_nan=False)
            with self._lock:
                self.view, self.rig, self._signature, self._read_at = view, rig, signature, now
                if body != self._body:
                    self._body, self.version = body, self.version + 1
                    self._wake()

    def refresh_logged(self, force: bool = False) -> None:
        """``refresh``, logging instead of raising: the pages keep the last state they got."""
        try:
            self.refresh(force)
        except Exception:  # noqa: BLE001 - a monitor must never stop on a bad read
            log.exception("monitor: reading the session %s failed", self.session_dir)

    def payload(self) -> tuple[int, bytes]:
        """(version, the state JSON with the server's clock, for the page's "ago" texts)."""
        with self._lock:
            body = self._body[:-1] + ", " if len(self._body) > 2 else "{"
            return self.version, f'{body}"server_time": {time.time()!r}}}'.encode()

    async def wait_newer(self, version: int, timeout: float) -> None:
        """Wait (in the event loop) until the state is newer than ``version``, the hub closes, or
        ``timeout`` seconds pass."""
        waiter = (asyncio.get_running_loop(), asyncio.Event())
        with self._lock:
            if self.version > version or self.closed:
                return
            self._waiters.add(waiter)
        try:
            await asyncio.wait_for(waiter[1].wait(), timeout)
        except asyncio.TimeoutError:
            pass
        finally:
            with self._lock:
                self._waiters.discard(waiter)

    def close(self) -> None:
        with self._lock:
            self.closed = True
            self._wake()

    def _wake(self) -> None:
        """Wake every waiting stream (called with ``_lock`` held, from any thread)."""
        for loop, event in self._waiters:
            try:
                loop.call_soon_threadsafe(event.set)
            except RuntimeError:   # its loop is closed: the server stopped
                pass

    def _signature_now(self) -> tuple:
        journal = journal_path(self.session_dir)
        paths = (journal, journal.with_name(journal.name + "-wal"), self.session_dir / REPORT_FILE, self.session_dir)
        out = []
        for p in paths:
            try:
                st = p.stat()
                out.append((st.st_mtime_ns, st.st_size, st.st_ino))
            except OSError:
                out.append(None)
        return tuple(out)

    def _rig(self, view):
        from goniofrost.monitor.rig_pose import rig_from_text

        if not view.rig_text:
            return None
        try:
            return rig_from_text(view.rig_text, f"{journal_path(view.session_dir)} (meta.rig_text)")
        except GoniofrostError as exc:
            log.warning("monitor: no pose drawings: %s", exc)
            return None


class PictureCache:
    """The latest picture of one kind: made by one thread at a time, at most PICTURE_DUTY of the time."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.key, self.data, self.info, self.error = None, None, {}, None
        self._busy, self._next_at = False, 0.0
        self.closing = False  # the server is stopping: make the last pictures without waiting

    def get(self, key, make) -> tuple:
        """(key shown, PNG bytes or None, info, error text or None, seconds until a newer one may come).

        ``make()`` returns (key, png, info) for the session as it is now, or raises PictureUnavailable.
        """
        with self._lock:
            now = time.monotonic()
            if key == self.key or self._busy or (now < self._next_at and not self.closing):
                wait = 0.0 if key == self.key else max(self._next_at - now, 0.2)
                return self.key, self.data, self.info, self.error, wait
            self._busy = True
        t0 = time.monotonic()
        made, data, info, error = key, None, {}, None
        try:
            made, data, info = make()
        except (PictureUnavailable, GoniofrostError) as exc:
            error = str(exc)
        finally:
            took = time.monotonic() - t0
            with self._lock:
                self.key, self.data, self.info, self.error = made, data, info, error
                took = (info or {}).get("work_s", took)  # a first picture's one-off loading does not count
                gap = min(PICTURE_MAX_GAP_S, max(PICTURE_MIN_GAP_S, took / PICTURE_DUTY))
                self._busy, self._next_at = False, time.monotonic() + gap
        return made, data, info, error, 0.0


class Site:
    """One session served: its state hub and its latest frame and preview."""

    def __init__(self, session_dir, attached: bool) -> None:
        self.hub = StateHub(session_dir, attached)
        self.frames, self.previews = PictureCache(), PictureCache()

    def final_page_served(self) -> bool:
        """Every open page has the last state, and the pictures of the last sample were made."""
        hub, view = self.hub, self.hub.view
        if any(v < hub.version for v in list(hub.clients.values())):
            return False
        if not view.done:
            return True
        latest = max(view.done, key=lambda d: d.committed_utc).plan_index
        return self.frames.key == latest and self.previews.key == (view.plan_key, len(view.done))


class Sites:
    """The sessions one app serves: ``root`` itself, or (``catalogue``) the session folders the
    catalogue lists under it, each made on first use (no other path can be reached)."""

    def __init__(self, root, catalogue: bool, attached: bool = False) -> None:
        self.root, self.catalogue = Path(root), catalogue
        self.single = None if catalogue else Site(root, attached)
        self._named: dict[str, Site] = {}
        self._lock = threading.Lock()

    def get(self, name: str) -> Site | None:
        """The session folder NAME of the catalogue (blocking: it lists the root)."""
        from goniofrost.monitor.catalogue import session_folders

        with self._lock:
            if name not in self._named:
                folders = {p.name: p for p in session_folders(self.root)}
                if name not in folders:
                    return None
                self._named[name] = Site(folders[name], False)
            return self._named[name]

    def all(self) -> list[Site]:
        with self._lock:
            return [self.single] if self.single else list(self._named.values())
