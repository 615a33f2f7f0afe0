"""The in-memory scripted transport of tests/scripted.py can fail: a different byte, a byte too many,
a request never sent and a reply left unread (or thrown away) each fail, without waiting."""
from __future__ import annotations

import pytest

from scripted import ScriptedTransport

SCRIPT = [(b"1TP\r\n", b"1TP0\r\n")]


def test_exact_exchange_passes():
    line = ScriptedTransport(SCRIPT)
    line.write(b"1TP\r\n")
    assert line.read_until(b"\r\n") == b"1TP0\r\n"
    line.finish()


def test_a_different_byte_fails_at_once_and_at_finish():
    line = ScriptedTransport(SCRIPT)
    with pytest.raises(AssertionError, match="step 0: expected 31 54 50 0d 0a, got 31 54 53"):
        line.write(b"1TS\r\n")
    with pytest.raises(AssertionError, match="got 31 54 53"):
        line.finish()


def test_a_byte_after_the_script_fails():
    line = ScriptedTransport(SCRIPT)
    with pytest.raises(AssertionError, match="sent after the script: 31 54 45 0d 0a"):
        line.write(b"1TP\r\n1TE\r\n")


@pytest.mark.parametrize("drop", [False, True], ids=["left", "reset"])
def test_an_unread_reply_fails(drop):
    line = ScriptedTransport(SCRIPT)
    line.write(b"1TP\r\n")
    if drop:
        line.reset_input_buffer()
    with pytest.raises(AssertionError, match="6 reply bytes never read"):
        line.finish()


def test_a_request_never_sent_fails():
    line = ScriptedTransport(SCRIPT + [(b"1TS\r\n", b"1TS00000A\r\n")])
    line.write(b"1TP\r\n")
    line.read_until(b"\r\n")
    with pytest.raises(AssertionError, match="1 request\\(s\\) never sent, the first 31 54 53 0d 0a"):
        line.finish()


def test_silence_and_a_partial_reply_advance_the_clock_not_the_wall():
    line = ScriptedTransport([(b"1TP\r\n", b""), (b"1TP\r\n", b"1TP\r")], timeout=0.3)
    line.write(b"1TP\r\n")
    assert line.read_until(b"\r\n") == b"" and line.now_ms() == pytest.approx(300.0)
    line.write(b"1TP\r\n")
    assert line.read_until(b"\r\n") == b"1TP\r" and line.now_ms() == pytest.approx(600.0)
    line.finish()
