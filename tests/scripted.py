"""An in-memory transport that plays an exchange of exact bytes, in the manner of pymeasure's
``expected_protocol``: the test lists ``(request, reply)`` byte pairs, hands the transport to the
driver (``axis.connect(ScriptedTransport(...))``) and calls ``finish()``.

A request must arrive byte for byte: the first byte that differs, or any byte after the script
ended, fails at once (``AssertionError`` raised inside the driver's write, and kept for
``finish()``, since a driver may catch it on its way to stopping the axis). A reply is available
as soon as its request is complete; ``b""`` is silence and a shortened reply a damaged one.
``finish()`` also fails on a request never sent and on reply bytes never read (dropped by a
``reset_input_buffer`` included). Nothing waits: a read that finds nothing advances the
transport's own clock by its timeout (``now_ms()``, which dynamixel-sdk's reply timeout uses
through ``drivers.dynamixel._Port``) and returns what there is.
"""
from __future__ import annotations


class ScriptedTransport:
    """pyserial's interface (``drivers.transport.ByteTransport``) over a script of exact bytes."""

    def __init__(self, script, timeout: float | None = 0.1) -> None:
        self.script = [(bytes(req), bytes(rep)) for req, rep in script]
        self.timeout = timeout
        self.problems: list[str] = []
        self.is_open = True
        self._step = 0             # the next (request, reply) pair
        self._sent = bytearray()   # bytes of the current request received so far
        self._rx = bytearray()     # reply bytes the client has not read
        self._dropped = 0          # reply bytes thrown away unread by reset_input_buffer
        self._clock_ms = 0.0

    # ----- the client's side ------------------------------------------------------------------
    def write(self, data: bytes) -> int:
        for i, byte in enumerate(bytes(data)):
            if self._step == len(self.script):
                self._fail(f"sent after the script: {bytes(data[i:]).hex(' ')}")
            request, reply = self.script[self._step]
            self._sent.append(byte)
            if request[:len(self._sent)] != self._sent:
                self._fail(f"step {self._step}: expected {request.hex(' ')}, got {bytes(self._sent).hex(' ')}")
            if len(self._sent) == len(request):
                self._rx += reply
                self._sent.clear()
                self._step += 1
        return len(data)

    def read(self, size: int = 1) -> bytes:
        if not self._rx:
            self._wait()
        out, self._rx = bytes(self._rx[:size]), self._rx[size:]
        return out

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        end = self._rx.find(expected)
        if end < 0:
            self._wait()
            end = len(self._rx)
        else:
            end += len(expected)
        out, self._rx = bytes(self._rx[:end]), self._rx[end:]
        return out

    def reset_input_buffer(self) -> None:
        self._dropped += len(self._rx)
        self._rx.clear()

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def now_ms(self) -> float:
        """The transport's clock (ms): it advances only while a read waits for nothing."""
        return self._clock_ms

    def close(self) -> None:
        self.is_open = False

    # ----- the test's side --------------------------------------------------------------------
    def _wait(self) -> None:
        self._clock_ms += 1000.0 * (self.timeout or 0.001)

    def _fail(self, problem: str) -> None:
        self.problems.append(problem)
        raise AssertionError(problem)

    def finish(self) -> None:
        """Assert the exchange was exact: every request sent, nothing more, every reply read."""
        assert self.problems == [], self.problems
        left = self.script[self._step:]
        assert not left, f"{len(left)} request(s) never sent, the first {left[0][0].hex(' ')}"
        unread = len(self._rx) + self._dropped
        assert unread == 0, f"{unread} reply bytes never read by the client"
