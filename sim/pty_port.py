"""The device end of a pseudo-terminal: a simulated serial device's "cable".

A client opens ``path`` with pyserial as it would a ``/dev/ttyUSB0``. The pty is made raw and its
slave fd kept open (PROTOCOLS.md, "Pseudo-terminals").
"""
from __future__ import annotations

import os
import pty
import select
import threading
import tty


class PtyPort:
    """The master side of a raw pty; ``path`` is what a client opens."""

    def __init__(self) -> None:
        self.master_fd, self._slave_fd = pty.openpty()
        tty.setraw(self._slave_fd)
        self.path = os.ttyname(self._slave_fd)
        self.closed = False

    def read(self, timeout: float) -> bytes:
        """Return the bytes waiting (up to 4096), or b'' after ``timeout`` real seconds."""
        if self.closed:
            return b""
        ready, _, _ = select.select([self.master_fd], [], [], timeout)
        if not ready:
            return b""
        try:
            return os.read(self.master_fd, 4096)
        except OSError:  # the client side vanished mid-read; nothing to deliver
            return b""

    def write(self, data: bytes) -> None:
        """Send bytes to the client (silently nothing once closed: the cable is pulled)."""
        if data and not self.closed:
            os.write(self.master_fd, data)

    def close(self) -> None:
        """Close both ends; a client still holding the path then reads EIO / hang-up."""
        if not self.closed:
            self.closed = True
            os.close(self.master_fd)
            os.close(self._slave_fd)


class PtyServedDevice:
    """Lifecycle shared by simulated serial devices: a pty served by one background thread.

    A subclass sets ``protocol`` and implements ``_serve()`` (loop while ``self._running``,
    reading and writing ``self._port``) and ``_endpoint_fields()`` (its id/address and baud).
    """

    protocol = ""

    def _init_serving(self) -> None:
        self._port: PtyPort | None = None
        self._thread: threading.Thread | None = None
        self._running = False

    def start(self) -> dict:
        """Open the pty and start serving; return the endpoint entry ``goniofrost sim`` prints."""
        self._port = PtyPort()
        self._running = True
        self._thread = threading.Thread(target=self._serve, name=f"sim-{self.protocol}", daemon=True)
        self._thread.start()
        return {"protocol": self.protocol, "endpoint": self._port.path, **self._endpoint_fields()}

    def stop(self) -> None:
        """Stop serving and close the pty (idempotent)."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _serve(self) -> None:
        raise NotImplementedError

    def _endpoint_fields(self) -> dict:
        raise NotImplementedError
