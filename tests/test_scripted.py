"""The scripted transports of tests/scripted.py can fail: a different byte, a byte too many and a
reply left unread each fail ``finish()``, on a pty and on a loopback socket."""
from __future__ import annotations

import socket

import pytest
import serial

from scripted import ScriptedLine, ScriptedSocket

SCRIPT = [(b"1TP\r\n", b"1TP0\r\n")]


def _serial(line):
    return serial.Serial(line.port.path, 57600, timeout=1.0)


def test_pty_exact_exchange_passes():
    line = ScriptedLine(SCRIPT)
    with _serial(line) as port:
        port.write(b"1TP\r\n")
        assert port.read_until(b"\r\n") == b"1TP0\r\n"
    line.finish()


@pytest.mark.parametrize("sent, read, problem", [
    (b"1TS\r\n", False, "expected 31 54 50 0d 0a, got 31 54 53 0d 0a"),
    (b"1TP\r\n1TE\r\n", True, "sent after the script: 31 54 45 0d 0a"),
    (b"1TP\r\n", False, "6 reply bytes never read"),
], ids=["different", "too-many", "unread"])
def test_pty_exchange_fails_on(sent, read, problem):
    line = ScriptedLine(SCRIPT)
    with _serial(line) as port:
        port.write(sent)
        if read:
            port.read_until(b"\r\n")
        elif problem.endswith("never read"):
            assert line.played.wait(5)  # the reply went out; closing now leaves it unread
    with pytest.raises(AssertionError, match=problem):
        line.finish()


@pytest.mark.parametrize("read, problem", [(True, None), (False, "reply bytes never read")],
                         ids=["exact", "unread"])
def test_socket_exchange_checks_the_reply_was_read(read, problem):
    server = ScriptedSocket(SCRIPT)
    with socket.create_connection((server.host, server.port), timeout=2) as client:
        client.sendall(b"1TP\r\n")
        if read:
            assert client.recv(64) == b"1TP0\r\n"
        else:
            assert server.played.wait(5)  # the reply went out; closing now leaves it unread
    if problem is None:
        server.finish()
    else:
        with pytest.raises(AssertionError, match=problem):
            server.finish()
