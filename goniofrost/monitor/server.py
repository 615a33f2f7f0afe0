"""Serve the monitor app (``monitor.app``) with uvicorn on a thread of its own.

``AppServer`` binds the address itself (a taken port or a foreign address is a one-line
MonitorError, port 0 picks a free one, ``url`` is what to print), runs uvicorn on a daemon thread
without signal handlers, and stops within about SHUTDOWN_S; ``MonitorServer`` serves
``monitor_app`` with it and on ``close`` first pushes the final state to the open pages. Its
protocol (``_Protocol``) closes a connection with no full request head within IDLE_TIMEOUT_S, lets
at most MAX_WAITING wait at once (oldest closed first), and drops a client that reads nothing for
WRITE_TIMEOUT_S.
"""
from __future__ import annotations

import errno
import logging
import socket
import threading
import time
from collections import OrderedDict

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from goniofrost.core.errors import GoniofrostError
from goniofrost.monitor import DEFAULT_PORT
from goniofrost.monitor.app import monitor_app

FINAL_PUSH_S = 3.0         # on close, wait this long at most for pages to get the last state and pictures
SHUTDOWN_S = 0.25          # then at most this long for answers under way (a long download is cut)
START_S = 30.0             # the server thread answers by then (importing the app on a loaded host)
LISTEN_BACKLOG = 128       # connections the kernel queues before the event loop takes them
MAX_WAITING = 512          # connections waiting for their request head
IDLE_TIMEOUT_S = 10.0      # a connection without a full request head by then is closed
WRITE_TIMEOUT_S = 30.0     # a client that reads nothing for this long loses its connection
MAX_HEAD_BYTES = 128 * 1024  # a request head longer than this is answered 400 by h11

# uvicorn's own lines (start, stop, a malformed request, an error in a view) stay off the
# capture's terminal unless the program configures logging: no last-resort printing to stderr.
logging.getLogger("uvicorn").addHandler(logging.NullHandler())


class MonitorError(GoniofrostError):
    """The monitor cannot serve (e.g. its port is taken)."""


def _bind_remedy(exc: OSError) -> str:
    """What to change when the address cannot be bound: a name that does not resolve or an address
    this computer does not have is the --host's problem, anything else (a port in use, a
    privileged port) the --port's."""
    if isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL:
        return "pass another --host (an address of this computer, e.g. 127.0.0.1)"
    return "pass another --port (0 picks a free one)"


def listen(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port``; MonitorError saying what to change otherwise."""
    sock = None
    try:
        family, _, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(LISTEN_BACKLOG)
        return sock
    except OSError as exc:
        if sock is not None:
            sock.close()
        raise MonitorError(f"monitor: cannot serve on {host}:{port} ({exc.strerror or exc}); "
                           f"{_bind_remedy(exc)}") from None


class AppServer:
    """Serve the ASGI ``app`` (one made by ``monitor.app``, or an app that mounts its routes) on
    ``host:port`` (port 0: any free port) with uvicorn on a daemon thread. ``start()`` returns once
    it answers; ``close()`` stops it. Raises MonitorError if the address cannot be bound."""

    def __init__(self, app, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        self.app, self.socket = app, listen(host, port)
        self.host, self.port = host, self.socket.getsockname()[1]
        protocol = type("Protocol", (_Protocol,), {"waiting": OrderedDict()})
        self.uvicorn = uvicorn.Server(uvicorn.Config(
            app, http=protocol, lifespan="on", log_config=None, access_log=False, proxy_headers=False,
            server_header=False, headers=[("server", "goniofrost-monitor")], backlog=LISTEN_BACKLOG,
            timeout_graceful_shutdown=SHUTDOWN_S, h11_max_incomplete_event_size=MAX_HEAD_BYTES))
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '[::]') else host}:{self.port}/"

    def start(self):
        """Serve on a daemon thread; return once it answers (MonitorError if it could not start)."""
        self._thread = threading.Thread(target=self.uvicorn.run, kwargs={"sockets": [self.socket]},
                                        name="monitor", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + START_S
        while not self.uvicorn.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                self.socket.close()
                raise MonitorError(f"monitor: the server on {self.url} did not start")
            time.sleep(0.01)
        return self

    def close(self) -> None:
        """Stop serving: answers under way get SHUTDOWN_S to end, then they are cut."""
        self.uvicorn.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=SHUTDOWN_S + 5)
        self.socket.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


class MonitorServer(AppServer):
    """Serve the monitor page of ``session_dir`` on ``host:port`` (port 0: any free port).

    ``attached``: the server runs inside the capture's own process (it then knows the capture is
    alive); ``catalogue``: ``session_dir`` is a folder of sessions. ``close(ended_message)``
    pushes the final state to the open pages, then stops.
    """

    def __init__(self, session_dir, host: str = "127.0.0.1", port: int = DEFAULT_PORT, attached: bool = False,
                 catalogue: bool = False) -> None:
        app = monitor_app(session_dir, catalogue=catalogue, attached=attached, host=host)
        self.sites = app.state.sites
        super().__init__(app, host, port)

    def close(self, ended_message: str | None = None) -> None:
        """Push the final state (with ``ended_message`` when the capture failed outside the journal)
        to the connected pages, then stop serving."""
        site = self.sites.single
        try:
            if site is not None:
                site.frames.closing = site.previews.closing = True
                site.hub.ended_message = ended_message
                site.hub.refresh_logged(force=True)
                deadline = time.monotonic() + FINAL_PUSH_S
                while time.monotonic() < deadline and site.hub.clients and not site.final_page_served():
                    time.sleep(0.02)
        finally:
            for each in self.sites.all():
                each.hub.close()   # the event streams send what they have and end
            super().close()


class _Protocol(H11Protocol):
    """uvicorn's h11 protocol with the limits on waiting and stalled connections (module doc);
    ``waiting`` (connections without a request head yet, oldest first) is one per server."""

    waiting: OrderedDict

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        self._stall = None
        self._late = self.loop.call_later(IDLE_TIMEOUT_S, self._drop)
        self.waiting[self] = None
        while len(self.waiting) > MAX_WAITING:
            next(iter(self.waiting))._drop()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.cycle is not None:   # a request head arrived
            self._admitted()

    def connection_lost(self, exc) -> None:
        self._admitted()
        self.resume_writing()
        super().connection_lost(exc)

    def pause_writing(self) -> None:
        super().pause_writing()
        if self._stall is None:
            self._stall = self.loop.call_later(WRITE_TIMEOUT_S, self.transport.abort)

    def resume_writing(self) -> None:
        super().resume_writing()
        if self._stall is not None:
            self._stall.cancel()
            self._stall = None

    def _admitted(self) -> None:
        self._late.cancel()
        self.waiting.pop(self, None)

    def _drop(self) -> None:
        self._admitted()
        self.transport.close()
