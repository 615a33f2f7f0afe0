"""The monitor's HTTP server: the standard library's ``ThreadingHTTPServer`` and server-sent events.

GET and HEAD only, on 127.0.0.1 by default: the page, its static files, ``/api/state`` (the page
state as JSON), ``/api/events`` (server-sent events), ``/api/frame.png``, ``/api/preview.png``
and ``/files/NAME`` (inside the session folder only); on a folder of sessions the catalogue at
``/`` and each session under ``/s/NAME/``. Connections wait for their request head on one
selector thread (``WaitingRoom``) and are served by a bounded pool; files are streamed in
chunks. The routes, the limits and why the standard library: docs/explanations/monitor.md."""
from __future__ import annotations

import errno
import io
import json
import logging
import mimetypes
import selectors
import shutil
import socket
import threading
import time
from collections import OrderedDict
import queue
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, HTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from goniofrost.core.errors import GoniofrostError
from goniofrost.monitor import DEFAULT_PORT
from goniofrost.monitor.images import PictureUnavailable, frame_png, preview_png
from goniofrost.monitor.safe_path import UnsafePath, session_file, shown
from goniofrost.monitor.session_view import REPORT_FILE, journal_path, read_session
from goniofrost.monitor.status import page_state

log = logging.getLogger(__name__)

POLL_S = 0.25              # journal change check while a page is connected
TIME_REFRESH_S = 2.0       # re-derive the state this often even unchanged (stall detection)
HEARTBEAT_S = 15.0         # an SSE comment keeps idle connections open through proxies
PICTURE_DUTY = 0.03        # pictures take at most ~3 % of one core
PICTURE_MIN_GAP_S = 0.5
PICTURE_MAX_GAP_S = 5.0    # ... but never older than this (a first picture also loads the model)
SHUTDOWN_POLL_S = 0.05     # how soon serve_forever notices close()
FINAL_PUSH_S = 3.0         # on close, wait this long at most for pages to get the last state and pictures
LISTEN_BACKLOG = 128       # connections the kernel queues before the accept thread takes them
MAX_WORKERS = 16           # threads answering requests (event streams included)
MAX_EVENT_STREAMS = 8      # open pages at once: the others' event streams are answered 503
MAX_TRANSFERS = 4          # /files/ answers streaming at once
MAX_WAITING = 512          # connections waiting for their request head
IDLE_TIMEOUT_S = 10.0      # a connection without a full request head by then is closed
WRITE_TIMEOUT_S = 30.0     # a client that reads nothing for this long loses its connection
MAX_HEAD_BYTES = 128 * 1024  # a request head longer than this is handed on as it is (414 / 431)
FILE_CHUNK = 256 * 1024
WORKER_IDLE_S = 5.0        # a pool thread with nothing to do this long ends (threads return to normal)
LOOPBACK = ("127.0.0.1", "localhost", "::1")
STATIC = ("index.html", "monitor.js", "monitor.css")
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


class MonitorError(GoniofrostError):
    """The monitor cannot serve (e.g. its port is taken)."""


class StateHub:
    """The session's current page state, re-read when the journal changes, shared by every page."""

    def __init__(self, session_dir, attached: bool) -> None:
        self.session_dir, self.attached = Path(session_dir), attached
        self.ended_message: str | None = None
        self.view = read_session(self.session_dir)
        self.rig = None
        self.version, self.closed, self.clients = 0, False, {}
        self._body, self._signature, self._read_at = "{}", None, 0.0
        self._cond, self._read_lock = threading.Condition(), threading.Lock()

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
            with self._cond:
                self.view, self.rig, self._signature, self._read_at = view, rig, signature, now
                if body != self._body:
                    self._body, self.version = body, self.version + 1
                    self._cond.notify_all()

    def refresh_logged(self, force: bool = False) -> None:
        """``refresh``, logging instead of raising: the pages keep the last state they got."""
        try:
            self.refresh(force)
        except Exception:  # noqa: BLE001 - a monitor must never stop on a bad read
            log.exception("monitor: reading the session %s failed", self.session_dir)

    def payload(self) -> tuple[int, bytes]:
        """(version, the state JSON with the server's clock, for the page's "ago" texts)."""
        with self._cond:
            body = self._body[:-1] + ", " if len(self._body) > 2 else "{"
            return self.version, f'{body}"server_time": {time.time()!r}}}'.encode()

    def wait_newer(self, version: int, timeout: float) -> int:
        """Block until the state is newer than ``version``, the hub closes, or ``timeout``."""
        with self._cond:
            self._cond.wait_for(lambda: self.version > version or self.closed, timeout)
            return self.version

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()

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


def _bind_remedy(exc: OSError) -> str:
    """What to change when the address cannot be bound: a name that does not resolve or an address
    this computer does not have is the --host's problem (the message said to pass another --port
    for --host 999.1.1.1), anything else (a port in use, a privileged port) the --port's."""
    if isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL:
        return "pass another --host (an address of this computer, e.g. 127.0.0.1)"
    return "pass another --port (0 picks a free one)"


class MonitorServer:
    """Serve the monitor page of ``session_dir`` on ``host:port`` (port 0: any free port).

    ``attached``: the server runs inside the capture's own process (it then knows the capture is
    alive). Start with ``start()``; ``close(ended_message)`` pushes the final state to the open
    pages and stops. Raises MonitorError if the address cannot be bound.
    """

    def __init__(self, session_dir, host: str = "127.0.0.1", port: int = DEFAULT_PORT, attached: bool = False,
                 catalogue: bool = False) -> None:
        self.catalogue, self.root = catalogue, Path(session_dir)
        self.hub = None if catalogue else StateHub(session_dir, attached)
        self.frames, self.previews = PictureCache(), PictureCache()
        self._sites: dict[str, _Site] = {}
        self._sites_lock = threading.Lock()
        self.transfers = threading.BoundedSemaphore(MAX_TRANSFERS)
        self.streams = threading.BoundedSemaphore(MAX_EVENT_STREAMS)
        handler = type("Handler", (_Handler,), {"monitor": self})
        try:
            self.httpd = _PooledServer((host, port), handler)
        except OSError as exc:
            raise MonitorError(f"monitor: cannot serve on {host}:{port} ({exc.strerror or exc}); "
                               f"{_bind_remedy(exc)}") from None
        self.host = host
        self.port = self.httpd.server_address[1]
        self._threads: list[threading.Thread] = []
        self._stopping = threading.Event()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '[::]') else host}:{self.port}/"

    def start(self) -> "MonitorServer":
        for name, target in (("serve", lambda: self.httpd.serve_forever(poll_interval=SHUTDOWN_POLL_S)),
                             ("wait", self.httpd.waiting.run), ("poll", self._poll)):
            thread = threading.Thread(target=target, name=f"monitor-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def _poll(self) -> None:
        while not self._stopping.wait(POLL_S):
            for hub in self._hubs():
                if hub.clients:
                    hub.refresh_logged()

    def _hubs(self) -> list:
        with self._sites_lock:
            return [site.hub for site in self._sites.values()] if self.catalogue else [self.hub]

    def site(self, name: str):
        """The session NAME of the catalogue (its hub and pictures, made on first use); None unless
        NAME is a session folder the catalogue lists (no other path can be reached)."""
        from goniofrost.monitor.catalogue import session_folders

        with self._sites_lock:
            if name not in self._sites:
                folders = {p.name: p for p in session_folders(self.root)}
                if name not in folders:
                    return None
                self._sites[name] = _Site(StateHub(folders[name], False), self)
            return self._sites[name]

    def close(self, ended_message: str | None = None) -> None:
        """Push the final state (with ``ended_message`` when the capture failed outside the journal)
        to the connected pages, then stop serving."""
        self.frames.closing = self.previews.closing = True
        try:
            if self.hub is not None:
                self.hub.ended_message = ended_message
                self.hub.refresh_logged(force=True)
                deadline = time.monotonic() + FINAL_PUSH_S
                while time.monotonic() < deadline and self.hub.clients and not self._final_page_served():
                    time.sleep(0.02)
        finally:
            self._stopping.set()
            for hub in self._hubs():
                hub.close()
            self.httpd.shutdown()
            self.httpd.server_close()
            self.httpd.waiting.close()
            self.httpd.pool.shutdown()
            for thread in self._threads:
                thread.join(timeout=5)

    def _final_page_served(self) -> bool:
        """Every open page has the last state, and the pictures of the last sample were made."""
        view = self.hub.view
        if any(v < self.hub.version for v in list(self.hub.clients.values())):
            return False
        if not view.done:
            return True
        latest = max(view.done, key=lambda d: d.committed_utc).plan_index
        return self.frames.key == latest and self.previews.key == (view.plan_key, len(view.done))

    def __enter__(self) -> "MonitorServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


class _Site:
    """One session of a catalogue: what a request handler needs of a MonitorServer (its own state
    and pictures; the server's host and its limits on transfers and event streams, shared)."""

    def __init__(self, hub: StateHub, server: MonitorServer) -> None:
        self.hub, self.host = hub, server.host
        self.transfers, self.streams = server.transfers, server.streams
        self.frames, self.previews = PictureCache(), PictureCache()


class _Handler(BaseHTTPRequestHandler):
    """One request (a thread each). ``monitor`` is set on the subclass made per server."""

    monitor: MonitorServer
    server_version = "goniofrost-monitor"
    timeout = WRITE_TIMEOUT_S

    def setup(self) -> None:
        """``request`` is (socket, the request head the waiting room read): the head is read from
        memory, the answer written to the socket (HTTP/1.0: one request per connection)."""
        self.request, head = self.request
        super().setup()
        self.rfile = io.BufferedReader(io.BytesIO(head))

    def log_message(self, fmt, *args) -> None:  # the capture's terminal stays quiet
        log.debug("monitor %s: " + fmt, self.client_address[0], *args)

    # ----- methods ------------------------------------------------------------------------------
    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        if not self._host_allowed():
            return self._text(HTTPStatus.FORBIDDEN, "unexpected Host header")
        url = urlsplit(self.path)
        route, query = url.path, parse_qs(url.query)
        try:
            if self.monitor.catalogue:
                if route in ("/", "/index.html"):
                    return self._catalogue()
                if route.startswith("/s/"):
                    name, slash, rest = route[len("/s/"):].partition("/")
                    site = self.monitor.site(name)
                    if site is None:
                        return self._text(HTTPStatus.NOT_FOUND, f"no such session: {name[:64]}")
                    if not slash:  # the page's relative addresses need the slash
                        return self._send(HTTPStatus.MOVED_PERMANENTLY, "text/plain; charset=utf-8", b"",
                                          {"Location": f"/s/{name}/"})
                    self.monitor, route = site, "/" + rest  # this request only: the session's own routes
                elif not route.startswith("/static/") and route != "/favicon.ico":
                    return self._text(HTTPStatus.NOT_FOUND, f"no such page: {route}")
            if route in ("/", "/index.html"):
                return self._static("index.html")
            if route.startswith("/static/"):
                return self._static(route[len("/static/"):])
            if route == "/api/state":
                self.monitor.hub.refresh_logged()
                return self._send(HTTPStatus.OK, "application/json", self.monitor.hub.payload()[1])
            if route == "/api/events":
                return self._events()
            if route == "/api/frame.png":
                return self._frame(query)
            if route == "/api/preview.png":
                return self._preview(query)
            if route.startswith("/files/"):
                return self._file(route[len("/files/"):])
            if route == "/favicon.ico":
                return self._send(HTTPStatus.NO_CONTENT, "image/x-icon", b"")
        except (BrokenPipeError, ConnectionResetError):
            return None
        return self._text(HTTPStatus.NOT_FOUND, f"no such page: {route}")

    def do_HEAD(self) -> None:  # noqa: N802
        self._head_only = True
        self.do_GET()

    def _refuse_write(self) -> None:
        self._text(HTTPStatus.METHOD_NOT_ALLOWED, "the monitor only reads the session", {"Allow": "GET, HEAD"})

    do_POST = do_PUT = do_DELETE = do_PATCH = _refuse_write  # noqa: N815

    # ----- routes -------------------------------------------------------------------------------
    def _catalogue(self) -> None:
        from goniofrost.monitor.catalogue import catalogue_html

        self._send(HTTPStatus.OK, "text/html; charset=utf-8", catalogue_html(self.monitor.root).encode())

    def _static(self, name: str) -> None:
        if name not in STATIC:
            return self._text(HTTPStatus.NOT_FOUND, f"no such page: {name}")
        data = resources.files("goniofrost.monitor").joinpath("static", name).read_bytes()
        kind = mimetypes.guess_type(name)[0] or "application/octet-stream"
        self._send(HTTPStatus.OK, f"{kind}; charset=utf-8", data)

    def _events(self) -> None:
        if not self.monitor.streams.acquire(blocking=False):
            return self._text(HTTPStatus.SERVICE_UNAVAILABLE, f"at most {MAX_EVENT_STREAMS} pages at once",
                              {"Retry-After": "5"})
        try:
            self._stream_events()
        finally:
            self.monitor.streams.release()

    def _stream_events(self) -> None:
        hub = self.monitor.hub
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self._security_headers()
        self.end_headers()
        me = object()
        hub.clients[me] = -1
        try:
            hub.refresh_logged()
            sent = -1
            while True:
                version, payload = hub.payload()
                if version > sent:
                    self.wfile.write(b"event: state\ndata: " + payload + b"\n\n")
                    sent = hub.clients[me] = version
                else:
                    self.wfile.write(b": keep-alive\n\n")
                self.wfile.flush()
                if hub.closed:
                    return
                hub.wait_newer(sent, HEARTBEAT_S)
        except (BrokenPipeError, ConnectionResetError, OSError):
            return
        finally:
            hub.clients.pop(me, None)

    def _frame(self, query) -> None:
        hub = self.monitor.hub
        hub.refresh_logged()   # the session as it is now, whether or not a page asked for the state
        wanted = _int(query, "sample")
        view = hub.view
        if not any(d.plan_index == wanted for d in view.done):
            return self._text(HTTPStatus.NOT_FOUND, f"sample {wanted} is not in the journal", {"X-Shows": str(wanted)})

        def make():
            png, info = frame_png(view, wanted)
            return wanted, png, info
        self._picture(self.monitor.frames.get(wanted, make), wanted, f"the frame of sample {wanted}")

    def _preview(self, query) -> None:
        hub = self.monitor.hub
        hub.refresh_logged()
        view, rig = hub.view, hub.rig
        wanted = (view.plan_key, _int(query, "done"))

        def make():
            png, info = preview_png(view, rig)
            return (view.plan_key, len(view.done)), png, info
        self._picture(self.monitor.previews.get(wanted, make), wanted, f"the preview from {wanted[1]} samples")

    def _picture(self, got, wanted, what: str) -> None:
        """An older picture may answer (X-Shows says which: the page asks again after
        X-Retry-After-Ms), but a message is only ever the one of the picture asked for."""
        key, data, info, error, wait = got
        shows = key[1] if isinstance(key, tuple) else key
        headers = {"X-Shows": str(shows), "X-Retry-After-Ms": str(int(wait * 1000)),
                   "X-Info": json.dumps(info or {})}
        if data is None:
            message = error if key == wanted and error else f"{what} is not made yet"
            return self._text(HTTPStatus.SERVICE_UNAVAILABLE, message, headers)
        self._send(HTTPStatus.OK, "image/png", data, headers)

    def _file(self, requested: str) -> None:
        try:
            path = session_file(self.monitor.hub.session_dir, requested)
        except UnsafePath as exc:
            return self._text(HTTPStatus.NOT_FOUND, str(exc))
        kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        if kind.startswith("text/") or kind == "application/json":
            kind += "; charset=utf-8"
        if not self.monitor.transfers.acquire(blocking=False):
            return self._text(HTTPStatus.SERVICE_UNAVAILABLE, f"at most {MAX_TRANSFERS} file transfers at once",
                              {"Retry-After": "1"})
        try:
            self._stream_file(path, kind, requested)
        finally:
            self.monitor.transfers.release()

    def _stream_file(self, path: Path, kind: str, requested: str) -> None:
        """The file in FILE_CHUNK pieces (its size from the open file: a file replaced meanwhile is
        sent whole as it was opened)."""
        import os

        try:
            source = open(path, "rb")   # noqa: SIM115 - closed below
        except OSError as exc:
            return self._text(HTTPStatus.NOT_FOUND, f"refused path {shown(requested)}: {exc.strerror or exc}")
        with source:
            size = os.fstat(source.fileno()).st_size
            self._head(HTTPStatus.OK, kind, size)
            if not getattr(self, "_head_only", False):
                shutil.copyfileobj(source, self.wfile, FILE_CHUNK)

    # ----- answers ------------------------------------------------------------------------------
    def _host_allowed(self) -> bool:
        """Against DNS rebinding: on a loopback address, only loopback Host names are answered."""
        if self.monitor.host not in LOOPBACK:
            return True
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]")
        return host in LOOPBACK

    def _security_headers(self) -> None:
        self.send_header("Content-Security-Policy", CSP)
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")

    def _send(self, status, kind: str, data: bytes, headers: dict | None = None) -> None:
        self._head(status, kind, len(data), headers)
        if not getattr(self, "_head_only", False):
            self.wfile.write(data)

    def _head(self, status, kind: str, length: int, headers: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(length))
        self.send_header("Cache-Control", "no-store")
        for name, value in (headers or {}).items():
            self.send_header(name, value)
        self._security_headers()
        self.end_headers()

    def _text(self, status, message: str, headers: dict | None = None) -> None:
        self._send(status, "text/plain; charset=utf-8", message.encode(), headers)


class _PooledServer(HTTPServer):
    """An HTTPServer whose accepted connections wait in a WaitingRoom, then are answered by a
    bounded pool (module doc). Errors of one connection are logged, never printed."""

    request_queue_size = LISTEN_BACKLOG

    def __init__(self, address, handler) -> None:
        super().__init__(address, handler)
        self.pool = WorkerPool(MAX_WORKERS, WORKER_IDLE_S)
        self.waiting = WaitingRoom(self._dispatch)

    def process_request(self, request, client_address) -> None:
        self.waiting.add(request, client_address)

    def _dispatch(self, sock: socket.socket, client_address, head: bytes) -> None:
        try:
            self.pool.submit(self._answer, sock, client_address, head)
        except RuntimeError:   # the pool is shut down: the server is closing
            _close(sock)

    def _answer(self, sock: socket.socket, client_address, head: bytes) -> None:
        try:
            sock.setblocking(True)
            self.finish_request((sock, head), client_address)
        except Exception:  # noqa: BLE001 - one connection's failure (a reset, a timeout) ends only it
            self.handle_error(sock, client_address)
        finally:
            self.shutdown_request(sock)

    def handle_error(self, request, client_address) -> None:
        log.debug("monitor: connection from %s failed", client_address, exc_info=True)


class WorkerPool:
    """At most ``size`` threads running submitted calls; a thread idle ``idle_s`` ends, so after a
    burst the process returns to its usual threads. (``concurrent.futures`` keeps its threads.)"""

    def __init__(self, size: int, idle_s: float) -> None:
        self.size, self.idle_s = size, idle_s
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._threads = self._idle = 0
        self._closed = False

    def submit(self, fn, *args) -> None:
        """Run ``fn(*args)`` on a pool thread (queued while all are busy); RuntimeError once shut down."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the pool is shut down")
            self._jobs.put((fn, args))
            if self._idle == 0 and self._threads < self.size:
                self._threads += 1
                threading.Thread(target=self._work, name="monitor-worker", daemon=True).start()

    def shutdown(self) -> None:
        """Run no more calls: queued ones are dropped, running ones finish."""
        with self._lock:
            self._closed = True
            for _ in range(self._threads):
                self._jobs.put(None)

    def _work(self) -> None:
        while True:
            with self._lock:
                self._idle += 1
            try:
                job = self._jobs.get(timeout=self.idle_s)
            except queue.Empty:
                with self._lock:
                    self._idle -= 1
                    if self._jobs.empty():   # checked under the lock submit puts under: no job is stranded
                        self._threads -= 1
                        return
                continue
            with self._lock:
                self._idle -= 1
            if job is None or self._closed:
                with self._lock:
                    self._threads -= 1
                return
            fn, args = job
            fn(*args)


class WaitingRoom:
    """Connections waiting for their request head, all on one selector thread.

    ``add(sock, address)`` from the accept thread; ``run()`` is the thread; a connection whose head
    is complete (a blank line, or MAX_HEAD_BYTES) goes to ``dispatch(sock, address, head)``; one
    that closes, fails or waits longer than IDLE_TIMEOUT_S is closed; beyond MAX_WAITING the
    oldest is closed.
    """

    def __init__(self, dispatch) -> None:
        self.dispatch = dispatch
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._selector.register(self._wake_r, selectors.EVENT_READ)
        self._new: list = []
        self._lock = threading.Lock()
        self._waiting: OrderedDict = OrderedDict()   # socket -> [address, deadline, head bytes]
        self._closed = False

    def add(self, sock: socket.socket, address) -> None:
        with self._lock:
            if self._closed:
                return _close(sock)
            self._new.append((sock, address))
        self._wake()

    def run(self) -> None:
        try:
            while not self._closed:
                for key, _ in self._selector.select(timeout=1.0):
                    if key.fileobj is self._wake_r:
                        self._drain_wake()
                    else:
                        self._read(key.fileobj)
                self._admit()
                self._expire(time.monotonic())
        finally:
            for sock in list(self._waiting):
                self._drop(sock)
            self._selector.close()
            self._wake_r.close()
            self._wake_w.close()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            pending, self._new = self._new, []
        self._wake()
        for sock, _ in pending:
            _close(sock)

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"x")
        except OSError:   # its buffer is full (the thread is awake anyway) or it is closed
            pass

    def _drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, OSError):
            pass

    def _admit(self) -> None:
        with self._lock:
            new, self._new = self._new, []
        deadline = time.monotonic() + IDLE_TIMEOUT_S
        for sock, address in new:
            sock.setblocking(False)
            self._waiting[sock] = [address, deadline, b""]
            self._selector.register(sock, selectors.EVENT_READ)
        while len(self._waiting) > MAX_WAITING:
            self._drop(next(iter(self._waiting)))

    def _read(self, sock: socket.socket) -> None:
        entry = self._waiting.get(sock)
        if entry is None:
            return
        try:
            data = sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            return self._drop(sock)
        if not data:
            return self._drop(sock)
        entry[2] += data
        head = entry[2]
        if b"\r\n\r\n" in head or b"\n\n" in head or len(head) >= MAX_HEAD_BYTES:
            self._selector.unregister(sock)
            del self._waiting[sock]
            self.dispatch(sock, entry[0], head)

    def _expire(self, now: float) -> None:
        for sock in [s for s, (_, deadline, _) in self._waiting.items() if deadline < now]:
            self._drop(sock)

    def _drop(self, sock: socket.socket) -> None:
        self._waiting.pop(sock, None)
        try:
            self._selector.unregister(sock)
        except (KeyError, ValueError):
            pass
        _close(sock)


def _close(sock: socket.socket) -> None:
    try:
        sock.close()
    except OSError:
        pass


def _int(query: dict, name: str) -> int:
    try:
        return int(query.get(name, ["-1"])[0])
    except ValueError:
        return -1
