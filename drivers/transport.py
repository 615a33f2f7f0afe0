"""The connections the rig layer opens and hands to the drivers: one byte-stream interface.

A driver never opens a port: it gets a ``ByteTransport`` (``open_serial``, ``open_tcp``, or an
in-memory one in tests). The interface is pyserial's: ``write``, ``read``, ``read_until``,
``reset_input_buffer``, ``in_waiting``, ``timeout`` (seconds), ``close``.
"""
from __future__ import annotations

import select
import socket
import termios
from typing import Protocol

import serial

from .errors import DeviceError

# What an unplugged or missing port raises: pyserial's errors, EIO, and termios.error (not an OSError).
PORT_ERRORS = (serial.SerialException, OSError, termios.error)


class ByteTransport(Protocol):
    """The byte stream a driver talks through (pyserial's interface)."""

    timeout: float | None

    def write(self, data: bytes) -> int | None: ...

    def read(self, size: int = 1) -> bytes: ...

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes: ...

    def reset_input_buffer(self) -> None: ...

    @property
    def in_waiting(self) -> int: ...

    def close(self) -> None: ...


def open_serial(name: str, path: str, baud: int, timeout_s: float, *, parity: str = "N",
                xonxoff: bool = False) -> serial.Serial:
    """Open a serial port 8 data bits, 1 stop bit; DeviceError naming the device when it cannot."""
    try:
        return serial.Serial(str(path), int(baud), bytesize=8, parity=parity, stopbits=1,
                             xonxoff=xonxoff, timeout=timeout_s)
    except PORT_ERRORS as exc:
        raise DeviceError(name, f"open {path}", None, f"cannot open port: {exc}") from exc


def open_tcp(name: str, host: str, port: int, timeout_s: float) -> "SocketTransport":
    """Connect to ``host:port``; DeviceError naming the device when nothing answers."""
    try:
        sock = socket.create_connection((str(host), int(port)), timeout=max(timeout_s, 1.0))
    except OSError as exc:
        raise DeviceError(name, f"connect {host}:{port}", None, f"cannot connect: {exc}") from exc
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # a request is one small frame
    return SocketTransport(sock, timeout_s, f"{host}:{port}")


class SocketTransport:
    """A connected TCP socket with pyserial's read/write interface (``timeout`` in seconds)."""

    def __init__(self, sock: socket.socket, timeout_s: float, where: str = "") -> None:
        self.sock, self.timeout, self.where = sock, float(timeout_s), where
        self._buffer = bytearray()
        self.is_open = True

    def write(self, data: bytes) -> int:
        self.sock.sendall(data)
        return len(data)

    def _fill(self, timeout: float | None) -> bool:
        """Wait up to ``timeout`` s for bytes; False on silence. ConnectionError once the peer closed."""
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return False
        data = self.sock.recv(4096)
        if not data:
            raise ConnectionError(f"{self.where}: connection closed by the device")
        self._buffer += data
        return True

    def read(self, size: int = 1) -> bytes:
        if not self._buffer:
            self._fill(self.timeout)
        out, self._buffer = bytes(self._buffer[:size]), self._buffer[size:]
        return out

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        while expected not in self._buffer and self._fill(self.timeout):
            pass
        end = self._buffer.find(expected)
        end = len(self._buffer) if end < 0 else end + len(expected)
        out, self._buffer = bytes(self._buffer[:end]), self._buffer[end:]
        return out

    def reset_input_buffer(self) -> None:
        self._buffer.clear()
        while self._fill(0):
            self._buffer.clear()

    @property
    def in_waiting(self) -> int:
        return len(self._buffer)

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self.sock.close()
