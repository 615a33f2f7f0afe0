"""Suspenders (``goniofrost.rig.suspenders``, ``goniofrost.capture.suspension``): the conditions as
pure checks; on the simulated rig, drills that dim or cut the lamp, open the interlock or silence
a drive suspend a run at the safe point between samples, on the simulated clock, and the run
resumes by itself, or when the operator says, or gives up on a device that stays silent.
Every wait is on the simulated clock at a high speed-up: nothing sleeps a fixed time."""
from __future__ import annotations

import logging
import sqlite3
from contextlib import closing
from pathlib import Path

import pytest
import yaml

from drivers.errors import DeviceTimeout
from goniofrost.app.cli import main
from goniofrost.capture.executor import StepExecutor
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import Suspension, SuspensionEnd
from goniofrost.capture.suspension import SuspendWatch
from goniofrost.core.errors import ConfigError
from goniofrost.rig.file import load_checked_rig
from goniofrost.rig.simulated import simulated_devices
from goniofrost.rig.suspenders import Reading, ResumeMode, SuspendReason, Suspenders

from test_session import M, capture_args, csv_indices, setup  # noqa: F401 - setup is the module fixture

REPO = Path(__file__).resolve().parents[1]
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # a silenced drive makes pymodbus log errors


# ----- the conditions, pure ---------------------------------------------------------------------
def test_each_condition_names_its_reason_and_a_clear_reading_none():
    s = Suspenders(lamp_floor=0.8, lamp_drift=0.05, device_silent=True)
    assert s.check(Reading(0.79, 1.0)) is SuspendReason.LAMP_LOW
    assert s.check(Reading(0.90, 1.0)) is SuspendReason.LAMP_DRIFT   # 10 % from the run's first reading
    assert s.check(Reading(1.04, 1.0)) is None
    assert s.check(Reading(1.04, 1.0, interlock_closed=False)) is SuspendReason.INTERLOCK_OPEN
    assert s.check(Reading(None, 1.0, silent="camera_arm")) is SuspendReason.DEVICE_SILENT
    assert Suspenders(lamp_floor=0.8).check(Reading(None, None, silent="camera_arm")) is None  # not asked
    assert Suspenders(lamp_drift=0.05).check(Reading(0.5, None)) is None  # no reference yet


def rig_doc(faults=(), **suspenders) -> dict:
    """The simulated rig file as a mapping, with these drills and suspenders."""
    doc = yaml.safe_load((REPO / "config" / "rigs" / "sim.yaml").read_text())
    doc["sim"]["faults"] = [dict(f) for f in faults]
    if suspenders:
        doc["suspenders"] = suspenders
    return doc


def write(doc: dict, path: Path) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize("suspenders, keypath, expected, found", [
    ({"lamp_flor": 0.8}, "suspenders.lamp_flor", "one of the keys lamp_floor, lamp_drift, device_silent, interlock, "
     "hold_clear_s, poll_s, resume, give_up_s", "unknown key 'lamp_flor'"),
    ({"lamp_floor": 1.5}, "suspenders.lamp_floor", "a number in (0, 1) (photodiode relative to nominal)", 1.5),
    ({"resume": "later"}, "suspenders.resume", "one of ['auto', 'operator']", "later"),
    ({"poll_s": 0}, "suspenders.poll_s", "a number of seconds > 0", 0),
    ({"interlock": {"device": "camera_arm"}}, "suspenders.interlock.input", "a discrete input address 0..0xFFFE",
     "nothing"),
    ({"interlock": {"device": "sample_yaw", "input": 0}}, "suspenders.interlock.device",
     "one of the rig's Modbus axes ['camera_arm']", "sample_yaw"),
])
def test_bad_suspender_keys_are_one_line_naming_file_key_expected_and_found(tmp_path, suspenders, keypath,
                                                                           expected, found):
    rig = write(rig_doc(**suspenders), tmp_path / "rig.yaml")
    with pytest.raises(ConfigError) as err:
        load_checked_rig(rig)
    assert (err.value.source, err.value.keypath, err.value.expected, err.value.found) == \
        (str(rig), keypath, expected, found)


def test_a_bad_suspender_key_ends_the_command_with_one_line_and_exit_2(setup, tmp_path, capsys):  # noqa: F811
    folder, rig, plan, _ = setup
    bad = write({**yaml.safe_load(rig.read_text()), "suspenders": {"hold_clear_s": -1}}, tmp_path / "rig.yaml")
    assert main(capture_args(bad, plan, tmp_path / "s")) == 2
    err = capsys.readouterr().err
    assert err == f"goniofrost capture: error: {bad}: suspenders.hold_clear_s: expected a number of seconds >= 0, " \
                  f"found -1\n"
    assert not (tmp_path / "s").exists()


# ----- a whole capture, suspended by a drilled lamp ------------------------------------------------
def suspensions(session: Path) -> list[Suspension]:
    with closing(Journal.open(session / "session.sqlite", read_only=True)) as journal:
        return journal.suspensions()


def test_a_dimmed_lamp_suspends_the_capture_which_resumes_by_itself_and_loses_no_sample(setup, tmp_path,  # noqa: F811
                                                                                       capsys):
    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"kind": "lamp_dim", "at_sample": 2, "level": 0.5, "duration_s": 28}]
    doc["suspenders"] = {"lamp_floor": 0.8, "hold_clear_s": 10, "poll_s": 5}
    session = tmp_path / "s"
    assert main(capture_args(write(doc, tmp_path / "rig.yaml"), plan, session, "--speedup", "200")) == 0
    assert csv_indices(session) == list(range(M))  # every sample once: 0 lost, 0 duplicated
    with closing(sqlite3.connect(session / "session.sqlite")) as db:
        assert db.execute("SELECT plan_index FROM samples ORDER BY plan_index").fetchall() == [(i,) for i in range(M)]
    [s] = suspensions(session)
    # dimmed at sample 2's safe point for 28 s: read clear at 30 s, held clear 10 s more
    assert (s.run, s.reason, s.plan_index, s.waited_s, s.end) == (1, "lamp_low", 2, 40.0, SuspensionEnd.RESUMED)
    assert s.started_utc <= s.ended_utc
    report = yaml.safe_load((session / "report.json").read_text())
    assert (report["suspensions"]["count"], report["suspensions"]["reasons"], report["suspensions"]["waited_s"]) == \
        (1, {"lamp_low": 1}, 40.0)
    assert "suspended 1 time(s) for 40 s of session clock (lamp_low 1)" in (session / "summary.txt").read_text()
    assert capsys.readouterr().err == ("goniofrost: run suspended before plan sample 2: lamp_low (photodiode 0.499 of "
                                       "nominal, below the floor 0.8)\n"
                                       "goniofrost: run resumed after 40 s (resumed)\n")


# ----- the watch on the simulated devices ------------------------------------------------------------
class Watched:
    """A SuspendWatch on the started simulated rig of ``doc``, its lamp on, journaling into a real journal."""

    def __init__(self, doc: dict, folder: Path, check_stop=lambda: None) -> None:
        self.rig = load_checked_rig(write(doc, folder / "rig.yaml"))
        self.folder, self.check_stop = folder, check_stop

    def __enter__(self) -> "Watched":
        self._devices = simulated_devices(self.rig, speedup=1000.0)
        hw = self._devices.__enter__()
        hw.lamp.on()
        self.journal = Journal.create(self.folder / "session.sqlite", {})
        self.simulation = hw.simulation
        self.watch = SuspendWatch(Suspenders.from_section(self.rig.suspenders), StepExecutor(hw, self.folder),
                                  self.journal, self.check_stop, lambda: 1)
        return self

    def __exit__(self, *exc) -> None:
        self.journal.close()
        self._devices.__exit__(*exc)


def test_a_cut_lamp_waiting_for_the_operator_stays_suspended_until_resumed(tmp_path):
    doc = rig_doc([{"kind": "lamp_cut", "at_sample": 3, "duration_s": 28}], lamp_floor=0.8, hold_clear_s=10,
                  poll_s=5, resume="operator")
    with Watched(doc, tmp_path) as w:
        watch = w.watch
        seen = []

        def operator(reading: Reading) -> None:   # resumes after the 10th reading, 50 s in
            seen.append((watch.waited, reading.photodiode > 0.8))
            if len(seen) == 10:
                watch.resume()

        watch.subscribe(operator)
        watch.may_continue(2)        # nothing due: returns at once
        w.simulation.arm_faults(3)
        watch.may_continue(3)
        assert seen[5:] == [(30.0, True), (35.0, True), (40.0, True), (45.0, True), (50.0, True)]  # clear, held
        assert [s[1] for s in seen[:5]] == [False] * 5
        [s] = w.journal.suspensions()
    assert (s.reason, s.plan_index, s.waited_s, s.end) == ("lamp_low", 3, 50.0, SuspensionEnd.OPERATOR)


def test_the_interlock_input_suspends_until_it_closes(tmp_path):
    doc = rig_doc([{"axis": "camera_arm", "kind": "interlock_open", "at_sample": 0, "duration_s": 12}],
                  interlock={"device": "camera_arm", "input": 3}, hold_clear_s=0, poll_s=5)
    with Watched(doc, tmp_path) as w:
        watch = w.watch
        watch.may_continue(0)   # the interlock closed: nothing to wait for
        w.simulation.arm_faults(0)
        watch.may_continue(0)
        [s] = w.journal.suspensions()
        assert w.simulation.device("camera_arm").requests[-1][-5:] == bytes([0x02, 0x00, 0x03, 0x00, 0x01])
    assert (s.reason, s.waited_s, s.end) == ("interlock_open", 15.0, SuspensionEnd.RESUMED)


def test_a_silent_drive_suspends_and_the_run_resumes_once_it_answers(tmp_path):
    doc = rig_doc([{"axis": "camera_arm", "kind": "silent", "at_sample": 0, "duration_s": 10}],
                  lamp_floor=0.5, hold_clear_s=0, poll_s=6)
    with Watched(doc, tmp_path) as w:
        watch = w.watch
        w.simulation.arm_faults(0)
        watch.may_continue(0)
        [s] = w.journal.suspensions()
    assert (s.reason, s.waited_s, s.end) == ("device_silent", 12.0, SuspensionEnd.RESUMED)


def test_a_drive_silent_beyond_give_up_ends_the_run_as_a_device_fault(tmp_path):
    doc = rig_doc([{"axis": "camera_arm", "kind": "silent", "at_sample": 0, "duration_s": 600}],
                  lamp_floor=0.5, poll_s=6, give_up_s=10)
    with Watched(doc, tmp_path) as w:
        watch = w.watch
        w.simulation.arm_faults(0)
        with pytest.raises(DeviceTimeout, match="camera_arm: answer the suspenders' reading: no answer for 12 s"):
            watch.may_continue(0)
        [s] = w.journal.suspensions()
    assert (s.reason, s.waited_s, s.end) == ("device_silent", 12.0, SuspensionEnd.GAVE_UP)


def test_a_stop_while_suspended_ends_the_suspension_as_stopped(tmp_path):
    from goniofrost.capture.signals import SessionInterrupted

    polls = []

    def stop_after_two() -> None:
        polls.append(1)
        if len(polls) == 3:
            raise SessionInterrupted("rig stop")

    doc = rig_doc([{"kind": "lamp_cut", "at_sample": 0, "duration_s": 600}], lamp_floor=0.8, poll_s=5)
    with Watched(doc, tmp_path, check_stop=stop_after_two) as w:
        watch = w.watch
        w.simulation.arm_faults(0)
        with pytest.raises(SessionInterrupted):
            watch.may_continue(0)
        [s] = w.journal.suspensions()
    assert (s.reason, s.waited_s, s.end) == ("lamp_low", 10.0, SuspensionEnd.STOPPED)


def suspension_rows(session: Path) -> list[tuple]:
    """(reason, end_kind) of every journaled suspension, read by a second connection."""
    path = session / "session.sqlite"
    try:
        with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1)) as db:
            return db.execute("SELECT reason, end_kind FROM suspensions ORDER BY id").fetchall()
    except sqlite3.OperationalError:  # not created yet
        return []


def test_sigint_while_suspended_stops_the_axes_switches_the_lamp_off_and_exits_130(setup, tmp_path):  # noqa: F811
    import signal
    import time

    from goniofrost.capture.records import RunStatus
    from test_session import start_capture

    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"kind": "lamp_cut", "at_sample": 1, "duration_s": 1e6}]   # never comes back
    doc["suspenders"] = {"lamp_floor": 0.8, "poll_s": 5}
    session = tmp_path / "s"
    proc = start_capture(write(doc, tmp_path / "rig.yaml"), plan, session, speedup="100")
    t_end = time.monotonic() + 60
    while suspension_rows(session) != [("lamp_low", None)]:   # the run is suspended, waiting
        assert proc.poll() is None and time.monotonic() < t_end, proc.stderr.read().decode()
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=30) == 130
    err = proc.stderr.read().decode()
    assert err.startswith("goniofrost: run suspended before plan sample 1: lamp_low (photodiode 0.000 of nominal")
    assert "goniofrost capture: interrupted by SIGINT at plan sample 1" in err and "the lamp is off" in err
    assert suspension_rows(session) == [("lamp_low", "stopped")]
    with closing(Journal.open(session / "session.sqlite", read_only=True)) as journal:
        _start, end = journal.last_run()
        assert end.status is RunStatus.STOPPED_BY_OPERATOR and end.lamp_off is True
        assert all(s.confirmed for s in end.stops) and journal.done_indices() == {0}
