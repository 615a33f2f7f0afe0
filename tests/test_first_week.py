"""An operator's first week on the simulated rig (issue 51): each finding as the operator met it."""
from __future__ import annotations

import io
import json
import re

import pytest

from goniofrost.app.cli import main

from test_rig_console import SIM_RIG, TEMPLATE, twins  # noqa: F401 - twins is a fixture
from test_session import setup, uninterrupted  # noqa: F401 - fixtures


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


# ----- item 8: a finished session ------------------------------------------------------------------
def _finished_session(uninterrupted, tmp_path):
    import shutil

    session = tmp_path / "s"
    shutil.copytree(uninterrupted, session)
    return session


def test_a_finished_session_says_it_is_finished_with_or_without_resume(setup, uninterrupted, tmp_path, capsys):
    # it answered "pass --resume to continue it", and --resume then only wrote the same results again
    from test_session import M, capture_args

    _, rig, plan, _ = setup
    session = _finished_session(uninterrupted, tmp_path)
    before = {p.name: p.read_bytes() for p in session.iterdir() if p.is_file()}
    expected = (f"goniofrost capture: error: {session}: this session is finished ({M} of {M} samples, finished): "
                f"nothing is left to capture; its results are in {session}; to measure again, choose a new "
                f"--session folder\n")
    for extra in ((), ("--resume",)):
        capsys.readouterr()
        assert main(capture_args(rig, plan, session, *extra)) == 2
        assert capsys.readouterr().err == expected
        assert {p.name: p.read_bytes() for p in session.iterdir() if p.is_file()} == before


def test_a_finished_session_without_its_results_writes_them_on_resume(setup, uninterrupted, tmp_path, capsys):
    # killed while writing its results: the journal holds every sample, --resume writes them
    from test_session import capture_args

    _, rig, plan, _ = setup
    session = _finished_session(uninterrupted, tmp_path)
    report = (session / "report.json").read_bytes()
    (session / "report.json").unlink()
    capsys.readouterr()
    assert main(capture_args(rig, plan, session)) == 2
    assert capsys.readouterr().err.endswith(f"its results are not written yet: pass --resume to write them, or "
                                            f"choose a new --session folder to measure again\n")
    assert main(capture_args(rig, plan, session, "--resume")) == 0
    assert (session / "report.json").is_file()


# ----- item 9: the template rig file ------------------------------------------------------------------
TO_FILL = ["name", "axes.camera_arm.driver.host", "axes.sample_yaw.driver.port", "axes.sample_tilt.driver.port",
           "camera.folder", "camera.intrinsics.focal_px", "camera.mount.distance_mm"]


def test_an_unedited_template_is_refused_with_the_keys_to_fill_in(capsys):
    # `rig check --offline` called the template "sound", its example addresses and ports included
    assert main(["rig", "check", "--rig", str(TEMPLATE), "--offline"]) == 2
    err = capsys.readouterr().err
    assert err == (f"goniofrost rig: error: {TEMPLATE}: 1 problem(s):\n  {TEMPLATE}: (top level): expected this "
                   f"rig's own value for each key marked !fill-in (the template's example), found "
                   f"'{len(TO_FILL)} keys to fill in: {', '.join(TO_FILL)}'\n")


def test_an_unedited_template_is_refused_by_every_loader(tmp_path):
    from goniofrost.capture.rig_file import load_checked_rig
    from goniofrost.core.errors import ConfigError

    with pytest.raises(ConfigError, match=f"found '{len(TO_FILL)} keys to fill in: name, axes.camera_arm"):
        load_checked_rig(TEMPLATE)


def test_the_template_filled_in_is_sound(tmp_path, capsys):
    filled = tmp_path / "lab.yaml"
    filled.write_text(TEMPLATE.read_text().replace("!fill-in ", ""))
    assert main(["rig", "check", "--rig", str(filled), "--offline"]) == 0
    assert "the rig file is sound (3 axes, a lamp, camera rawfile)" in capsys.readouterr().out


# ----- item 4: the return home the plan lists -------------------------------------------------------
def test_a_capture_returns_home_at_the_end_as_its_plan_says(setup, uninterrupted):
    # PLAN.json's return_home_s and planned_motion_s count the move home; the capture stayed at
    # the last sample's pose (and its report took the return out of the planned motion)
    from goniofrost.capture.journal import Journal
    from goniofrost.capture.records import EventKind
    from goniofrost.capture.rig_file import load_checked_rig

    _, rig, plan, _ = setup
    with Journal.open(uninterrupted / "session.sqlite", read_only=True) as journal:
        events, steps = journal.events(), journal.steps()
    assert [s["kind"] for s in steps][-2:] == ["LampOff", "Home"]
    last = [e for e in events if e["kind"] in (EventKind.HOME, EventKind.LAMP)][-2:]
    assert [e["message"] for e in last] == ["lamp off", "homed camera_arm, sample_yaw, sample_tilt"]
    home = dict(zip(load_checked_rig(rig).joint_names, load_checked_rig(rig).home))
    assert last[1]["data"] == pytest.approx(home, abs=0.1)
    report = json.loads((uninterrupted / "report.json").read_text())
    assert report["times_s"]["planned_motion"] == json.loads(plan.read_text())["planned_motion_s"]
