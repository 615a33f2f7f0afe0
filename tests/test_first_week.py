"""An operator's first week on the simulated rig (issue 51): each finding as the operator met it."""
from __future__ import annotations

import io
import json
import re

import pytest

from goniofrost.app.cli import main

from test_rig_console import SIM_RIG, TEMPLATE, twins  # noqa: F401 - twins is a fixture


class _Terminal(io.StringIO):
    """stdout as a terminal: what `rig status --watch` wrote to it, escapes included."""

    def isatty(self) -> bool:
        return True


STAMP = re.compile(r"^reading at \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC$")


def test_status_watch_stamps_each_reading_in_a_log(twins, capsys):
    # it printed one table a second with no time: a log of readings could not say when each was
    path, _ = twins
    capsys.readouterr()
    assert main(["rig", "status", "--rig", str(path), "--watch", "--interval", "0.05", "--count", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10 and "\x1b" not in "".join(lines)   # not a terminal: no cursor moves
    assert STAMP.match(lines[0]) and STAMP.match(lines[5])
    assert [line.split()[0] for line in lines[1:5]] == ["camera_arm", "sample_yaw", "sample_tilt", "lamp"]


def test_status_watch_json_stamps_each_reading(twins, capsys):
    path, _ = twins
    capsys.readouterr()
    assert main(["rig", "status", "--rig", str(path), "--json", "--watch", "--interval", "0.05", "--count", "2"]) == 0
    docs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(docs) == 2 and all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", d["time_utc"]) for d in docs)


def test_status_watch_redraws_in_place_on_a_terminal(twins, monkeypatch):
    # on a terminal it scrolled a new table each second; now the cursor goes back up over the last one
    path, _ = twins
    terminal = _Terminal()
    monkeypatch.setattr("sys.stdout", terminal)
    assert main(["rig", "status", "--rig", str(path), "--watch", "--interval", "0.05", "--count", "3"]) == 0
    text = terminal.getvalue()
    assert text.count("\x1b[5F\x1b[J") == 2 and text.startswith("reading at ")
    frames = [f for f in text.split("\x1b[5F\x1b[J")]
    assert len(frames) == 3 and all(STAMP.match(f.splitlines()[0]) for f in frames)
