"""Scripted transports: the far end of a pty or a loopback TCP socket plays an exchange of exact bytes.

A script is a list of ``(request, reply)`` byte strings. The far end waits for exactly
``request``, answers ``reply`` (b"" for silence), and moves on. ``finish()`` fails the test on the
first request that differs, on anything the client sent after the script ended, and on reply
bytes the client never read. The driver under test talks to it through its real transport
(pyserial, dynamixel-sdk's PortHandler, pymodbus): nothing of the driver is mocked.
"""
from __future__ import annotations

import array
import fcntl
import select
import socket
import termios
import threading
import time

from sim.pty_port import PtyPort

REQUEST_WAIT_S = 3.0  # real seconds to wait for each scripted request


class _Player:
    """Plays a script on ``_read(timeout)`` / ``_write(data)`` in a background thread."""

    quiet_s = 0.2  # after the script: how long to listen for bytes the client should not send

    def __init__(self, script) -> None:
        self.script, self.problems, self.leftover = list(script), [], b""
        self.played = threading.Event()  # set once every reply of the script went out
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        buf = b""
        for step, (request, reply) in enumerate(self.script):
            deadline = time.monotonic() + REQUEST_WAIT_S
            while len(buf) < len(request) and time.monotonic() < deadline:
                buf += self._read(0.05)
            got, buf = buf[:len(request)], buf[len(request):]
            if got != request:
                self.problems.append(f"step {step}: expected {request.hex(' ')}, got {got.hex(' ')}")
                return
            if reply:
                self._write(reply)
        self.played.set()
        self.leftover = buf + self._drain()

    def _drain(self) -> bytes:
        end, out = time.monotonic() + self.quiet_s, b""
        while time.monotonic() < end:
            out += self._read(0.05)
        return out

    def finish(self) -> None:
        """Wait for the player, close the transport and assert the exchange was exact."""
        self._thread.join(timeout=REQUEST_WAIT_S * (len(self.script) + 1))
        unread = self._unread_by_client()
        self._close()
        assert self.problems == [], self.problems
        assert self.leftover == b"", f"sent after the script: {self.leftover.hex(' ')}"
        assert unread == 0, f"{unread} reply bytes never read by the client"


class ScriptedLine(_Player):
    """A pty (``port.path`` is what the client opens) whose other end plays the script."""

    def __init__(self, script) -> None:
        super().__init__(script)
        self.port = PtyPort()
        self._start()

    def _read(self, timeout: float) -> bytes:
        return self.port.read(timeout)

    def _write(self, data: bytes) -> None:
        self.port.write(data)

    def _unread_by_client(self) -> int:
        """Bytes waiting in the client's input queue (the pty slave stays open in PtyPort)."""
        count = array.array("i", [0])
        fcntl.ioctl(self.port._slave_fd, termios.FIONREAD, count)
        return count[0]

    def _close(self) -> None:
        self.port.close()


class ScriptedSocket(_Player):
    """A loopback TCP server (``host``, ``port``) that plays the script to its first client.

    The client must close its connection before ``finish()``: closing with reply bytes unread
    makes Linux reset the connection, which counts as unread bytes.
    """

    quiet_s = REQUEST_WAIT_S  # wait for the client to close (EOF ends the wait at once)

    def __init__(self, script) -> None:
        super().__init__(script)
        self._server = socket.create_server(("127.0.0.1", 0))
        self.host, self.port = self._server.getsockname()
        self._conn: socket.socket | None = None
        self._eof, self._reset = False, False
        self._start()

    def _read(self, timeout: float) -> bytes:
        if self._conn is None:
            ready, _, _ = select.select([self._server], [], [], timeout)
            if not ready:
                return b""
            self._conn, _ = self._server.accept()
        if self._eof:
            time.sleep(timeout)
            return b""
        ready, _, _ = select.select([self._conn], [], [], timeout)
        if not ready:
            return b""
        try:
            data = self._conn.recv(4096)
        except ConnectionResetError:
            data, self._reset = b"", True
        self._eof = data == b""
        return data

    def _drain(self) -> bytes:
        end, out = time.monotonic() + self.quiet_s, b""
        while time.monotonic() < end and not self._eof:
            out += self._read(0.05)
        return out

    def _write(self, data: bytes) -> None:
        self._conn.sendall(data)

    def _unread_by_client(self) -> int:
        return 1 if self._reset else 0  # the count is unknown: a reset says "some"

    def _close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._server.close()
