"""The engine against small fakes of the Hardware contract (never mocks of a driver's methods):
every step journaled as it happens, the sample commits, and one stop path on any failure."""
from __future__ import annotations

import shutil
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest

from calib import validate_camera_section
from drivers.camera import CameraError
from drivers.errors import DeviceFault, DeviceTimeout
from goniofrost.rig.contract import Axis, Camera, Clock, Hardware, Lamp
from goniofrost.capture.engine import SessionEngine, SessionFault
from goniofrost.capture.options import SessionOptions
from goniofrost.capture.executor import BenchHardware
from goniofrost.rig.stop import stop_axes
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import EventKind, RunStatus
from goniofrost.rig.stop import AxisStop
from goniofrost.capture.session_steps import SessionSpec
from goniofrost.capture.signals import SessionInterrupted
from sim.camera_bench import direction, rig_like

from frame_script import CAMERA_MODEL, LADDER, render_table

AXES = ("theta_i", "theta_o", "phi_o")
CAMERA = validate_camera_section({"kind": "sim", "exposures_s": LADDER, "target_snr": 100.0, "dark_frames": 1,
                                  **CAMERA_MODEL, "marker_tolerance_px": 200.0,   # scripted frames: one pose
                                  "flat_frames": 2}, "test")
SAMPLES = [{"joints": {"theta_i": 0.0, "theta_o": 30.0 + 5 * i, "phi_o": 180.0 - 10 * i}, "theta_h_deg": 10.0 + i,
            "theta_d_deg": 20.0 + i, "phi_d_deg": 90.0, "theta_i_deg": 0.0, "theta_o_deg": 30.0 + 5 * i}
           for i in range(2)]
SPEC = SessionSpec(SAMPLES, (101, 102), AXES, CAMERA, {"theta_i": 0.0, "theta_o": 30.0, "phi_o": 180.0},
                   lambda j: rig_like(direction(j["theta_i"]), direction(j["theta_o"], j["phi_o"])))
CALIBRATION = (["Phase", "LampOff"] + ["Expose"] * 4 + ["LampOn", "SetTarget", "Expose", "Expose", "SetTarget",
               "SetTarget", "Expose", "SetTarget", "SaveCalibration"])
SAMPLE = ["Move", "Expose", "Commit"]


# ----- fakes of the contract -------------------------------------------------------------------
class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


class FakeStatus:
    """A move started at the clock's present time; waiting on it lets the clock reach its end."""

    def __init__(self, axis: "FakeAxis", start: float, target: float) -> None:
        self.axis, self.start, self.target = axis, start, target
        self.ends = axis.clock.t + abs(target - start) / axis.config.speed_deg_s

    def wait(self) -> float:
        self.axis.clock.t = max(self.axis.clock.t, self.ends)
        return self.target


class FakeAxis:
    """Moves at ``config.speed_deg_s`` on the fake clock; ``fail_on_move`` (1-based) raises an
    alarm instead; ``stop_error`` makes stop() fail; ``interrupt_on_move`` raises as a signal would."""

    def __init__(self, name: str, clock: FakeClock, fail_on_move: int | None = None, stop_error: bool = False,
                 interrupt_on_move: int | None = None) -> None:
        self.name, self.clock, self.config = name, clock, SimpleNamespace(speed_deg_s=10.0, accel_deg_s2=50.0)
        self.fail_on_move, self.stop_error, self.interrupt_on_move = fail_on_move, stop_error, interrupt_on_move
        self.deg, self.moves, self.stops, self.connected = 0.0, [], 0, True

    def move_to(self, deg: float) -> FakeStatus:
        self.moves.append(deg)
        if self.fail_on_move == len(self.moves):
            raise DeviceFault(self.name, f"move to {deg:g} deg", self.deg, ["alarm"])
        if self.interrupt_on_move == len(self.moves):
            raise SessionInterrupted("SIGINT")
        start, self.deg = self.deg, float(deg)
        return FakeStatus(self, start, self.deg)

    def home(self) -> FakeStatus:
        start, self.deg = self.deg, 0.0
        return FakeStatus(self, start, 0.0)

    def position(self) -> float:
        return self.deg

    def stop(self) -> None:
        self.stops += 1
        if self.stop_error:
            raise DeviceTimeout(self.name, "stop", None, "no reply")

    def confirm_stopped(self) -> float:
        return self.deg


class FakeLamp:
    def __init__(self) -> None:
        self.is_on = False

    def on(self) -> None:
        self.is_on = True

    def off(self) -> None:
        self.is_on = False

    def photodiode(self) -> float:
        return 1.0 if self.is_on else 0.0


class FakeCamera:
    """Copies the scripted frame of what it sees (the lamp off: dark) at the exposure asked for;
    ``journal`` (a path): records the journal's last two step rows, read by another connection,
    at every capture; ``fail(seen, exposure_s)`` true: a CameraError instead."""

    def __init__(self, table: dict, lamp: FakeLamp, journal: Path | None = None, fail=None) -> None:
        self.table, self.lamp, self.journal, self.fail = table, lamp, journal, fail
        self.target, self.taken, self.rows_seen = "sample", [], []

    def set_target(self, target: str) -> None:
        self.target = target

    def capture(self, exposure_s: float, path: Path):
        seen = self.target if self.lamp.is_on else "dark"
        if self.fail is not None and self.fail(seen, exposure_s):
            raise CameraError(f"fake camera: no frame of {exposure_s} s")
        if self.journal is not None:
            with sqlite3.connect(f"file:{self.journal}?mode=ro", uri=True) as db:
                self.rows_seen.append(db.execute("SELECT kind, status FROM steps ORDER BY id DESC LIMIT 2").fetchall())
        shutil.copyfile(self.table[seen, exposure_s], path)
        self.taken.append((seen, exposure_s, Path(path).name))
        return SimpleNamespace(path=Path(path))


@dataclass
class FakeHardware:
    axes: dict
    lamp: FakeLamp
    camera: FakeCamera
    clock: FakeClock
    simulated: bool = False
    extra: dict = field(default_factory=dict)
    simulation: object = None


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    return render_table(tmp_path_factory.mktemp("frames"))


def rig(table, journal: Path | None = None, camera_fail=None, **axis_options) -> FakeHardware:
    """Fake hardware; ``axis_options``: {axis name: FakeAxis keyword arguments}."""
    clock, lamp = FakeClock(), FakeLamp()
    axes = {name: FakeAxis(name, clock, **axis_options.get(name, {})) for name in AXES}
    return FakeHardware(axes, lamp, FakeCamera(table, lamp, journal, camera_fail), clock)


def run(hardware, session: Path):
    """One engine run on the session folder's journal (created on first use): (stats, steps, events, samples)."""
    path = session / "session.sqlite"
    journal = Journal.open(path) if path.exists() else Journal.create(path, {"plan": "test"})
    with journal:
        try:
            stats = SessionEngine(SPEC, hardware, journal, session, SessionOptions(progress=False)).run()
        finally:
            steps, events, samples = journal.steps(), journal.events(), journal.samples()
    return stats, steps, events, samples


# ----- tests ---------------------------------------------------------------------------------------
def test_the_fakes_and_the_real_drivers_satisfy_the_hardware_contract(table, tmp_path):
    from drivers.camera import FolderCamera
    from drivers.rig_devices import RigDevices
    from goniofrost.rig.hardware import RigHardware, WallClock
    from goniofrost.rig.file import load_checked_rig

    devices = RigDevices.from_rig(load_checked_rig(Path(__file__).parents[1] / "config" / "rigs" / "sim.yaml"))
    real = RigHardware(devices.axes, devices.lamp, FolderCamera(tmp_path, lambda t: None), WallClock())
    for hardware in (rig(table), real):
        assert isinstance(hardware, Hardware) and isinstance(hardware.lamp, Lamp)
        assert isinstance(hardware.camera, Camera) and isinstance(hardware.clock, Clock)
        assert all(isinstance(a, Axis) for a in hardware.axes.values()) and len(hardware.axes) == 3
    assert real.simulated is False and not isinstance(object(), Hardware)
    assert isinstance(BenchHardware(real.lamp, real.camera, real.clock), Hardware)


def test_every_step_is_journaled_as_it_happens_and_each_sample_commits(table, tmp_path):
    hardware = rig(table, journal=tmp_path / "session.sqlite")
    stats, steps, events, samples = run(hardware, tmp_path)
    kinds = ["Home", "LampOn", "Move", *CALIBRATION, "Phase", *SAMPLE, *SAMPLE, "LampOff", "Home"]
    assert [s["kind"] for s in steps] == kinds
    assert {(s["run"], s["status"]) for s in steps} == {(1, "done")}
    assert [s["plan_index"] for s in steps if s["kind"] in ("Move", "Commit")] == [None, 0, 0, 1, 1]
    assert steps[kinds.index("Expose")]["detail"] == {"exposure_s": 0.002, "file": "calibration/dark_e0_0.dng",
                                                      "index": None}
    # at every exposure the journal already showed that step running, after the previous one done
    assert hardware.camera.rows_seen == [[("Expose", "running"), (k, "done")] for k in
                                         [kinds[i - 1] for i, k in enumerate(kinds) if k == "Expose"]]
    assert ("dark", 0.128, "dark_e3_0.dng") in hardware.camera.taken

    assert [r.plan_index for r in samples] == [0, 1] and stats.captured == 2
    assert [r.joints for r in samples] == [s["joints"] for s in SAMPLES]
    assert all(r.committed_utc >= r.started_utc > 0 for r in samples)
    assert [e["kind"] for e in events] == ["session", "home", "lamp", "calibration", "lamp", "lamp", "calibration",
                                           "samples", "lamp", "home", "session"]
    assert (tmp_path / "calibration" / "calibration.npz").is_file()
    assert (tmp_path / "samples.csv").read_text().count("\n") == 3
    # motion time from the session clock, axes moving together at 10 deg/s: the white pose (phi_o
    # turns 180 deg), sample 0 (already there), sample 1 (phi_o turns 10 deg), home (phi_o turns 170 deg)
    assert stats.motion_s == pytest.approx(18.0 + 0.0 + 1.0 + 17.0)
    assert all(a.stops == 0 for a in hardware.axes.values())


def test_a_resumed_session_keeps_the_journaled_calibration_and_journals_its_own_run(table, tmp_path):
    first = rig(table, theta_o={"fail_on_move": 3})  # home, white pose, sample 0, then sample 1 fails
    with pytest.raises(SessionFault):
        run(first, tmp_path)
    stats, steps, events, samples = run(rig(table), tmp_path)
    second = [s["kind"] for s in steps if s["run"] == 2]
    assert second == ["Home", "LampOn", "Phase", *SAMPLE, "LampOff", "Home"]
    assert [s["plan_index"] for s in steps if s["run"] == 2 and s["kind"] == "Commit"] == [1]
    assert [r.plan_index for r in samples] == [0, 1] and stats.skipped == 1 and stats.captured == 1


def test_a_device_fault_stops_every_axis_once_switches_the_lamp_off_and_marks_the_step_failed(table, tmp_path):
    hardware = rig(table, theta_o={"fail_on_move": 3})
    with pytest.raises(SessionFault) as caught:
        run(hardware, tmp_path)
    message = str(caught.value)
    assert message.startswith("device fault at plan sample 1: theta_o: move to 35 deg: device fault: alarm")
    # theta_i moved first, theta_o refused its move, phi_o was not reached: each confirmed where it is
    assert "Stopped theta_i at 0.00 deg, theta_o at 30.00 deg, phi_o at 180.00 deg; the lamp is off. " \
           "1 of 2 samples are safe in" in message and message.endswith("run the same command with --resume")
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1] and hardware.lamp.is_on is False
    with Journal.open(tmp_path / "session.sqlite") as journal:
        last, events, (start, end) = journal.steps()[-1], journal.events(), journal.last_run()
    assert (last["kind"], last["plan_index"], last["status"]) == ("Move", 1, "failed")
    assert "alarm" in last["result"]["error"]
    assert [e["kind"] for e in events][-3:] == [EventKind.FAULT, EventKind.STOP, EventKind.LAMP]
    fault, stop, lamp = events[-3:]
    assert fault["axis"] == "theta_o" and fault["data"]["lamp_off"]
    # the typed run end: status, the terminal's words, the counts and the stop report as fields
    assert (end.status, end.reason, end.axis, end.plan_index) == (RunStatus.FAULT, message, "theta_o", 1)
    assert (end.samples_planned, end.samples_captured, end.batches, end.lamp_off) == (2, 1, 0, True)
    assert end.detail.startswith("theta_o: move to 35 deg: device fault: alarm") and end.stopped_early
    assert [(s.axis, s.confirmed) for s in end.stops] == [("theta_i", True), ("theta_o", True), ("phi_o", True)]
    assert (start.run, start.program, start.samples_done) == (1, "capture", 0)
    assert start.started_utc <= end.started_utc < end.ended_utc
    assert stop["message"] == "stopped theta_i at 0.00 deg, theta_o at 30.00 deg, phi_o at 180.00 deg"
    assert [s["confirmed"] for s in stop["data"]["stops"]] == [True, True, True]
    assert (lamp["message"], lamp["data"]) == ("lamp off", {"off": True, "error": None})


def test_a_failing_stop_is_reported_truthfully_and_the_other_axes_are_still_stopped(table, tmp_path):
    hardware = rig(table, theta_i={"stop_error": True}, phi_o={"fail_on_move": 2})
    with pytest.raises(SessionFault, match="device fault at plan sample 0: phi_o") as caught:
        run(hardware, tmp_path)
    # theta_i and theta_o had started their moves of sample 0 when phi_o refused its own
    assert "Stopped theta_o at 30.00 deg, phi_o at 180.00 deg; theta_i did not confirm the stop: it may still be " \
           "moving towards 0.0 deg; the lamp is off. Check the axes named above before anything else moves. " \
           "0 of 2 samples are safe" in str(caught.value)
    assert "every axis" not in str(caught.value).lower()
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1]
    with Journal.open(tmp_path / "session.sqlite") as journal:
        [fault] = [e for e in journal.events() if e["kind"] is EventKind.FAULT]
        _start, end = journal.last_run()
    assert [s.text() for s in end.stops if not s.confirmed] == [
        "theta_i did not confirm the stop: it may still be moving towards 0.0 deg"]
    assert end.stops[0] == AxisStop("theta_i", False, None, True, 0.0, "theta_i: stop: no reply")
    assert fault["data"]["stops"][0] == {"axis": "theta_i", "confirmed": False, "position_deg": None,
                                         "under_way": True, "moving_to": 0.0, "error": "theta_i: stop: no reply"}
    # the one stop path reports an axis that is not connected, never raises, and tries every axis
    hardware.axes["theta_o"].connected = False
    stops = stop_axes(hardware.axes)
    assert [s.text() for s in stops] == [
        "theta_i did not confirm the stop (it was not moving as far as this session knows)",
        "theta_o did not confirm the stop (it was not moving as far as this session knows)",
        "phi_o stopped at 180.00 deg"]
    assert stops[1].error == "not connected" and [a.stops for a in hardware.axes.values()] == [2, 1, 2]


def test_a_lamp_that_cannot_be_switched_off_is_reported(table, tmp_path):
    hardware = rig(table, theta_o={"fail_on_move": 3})

    def unreachable() -> None:
        raise DeviceTimeout("lamp", "write coil 0 off", None, "no reply")
    hardware.lamp.off = unreachable
    with pytest.raises(SessionFault) as caught:
        run(hardware, tmp_path)
    assert "; the lamp did not confirm it is off: it may still be on. " in str(caught.value)
    with Journal.open(tmp_path / "session.sqlite") as journal:
        lamp = journal.events()[-1]
    assert lamp["message"] == "the lamp did not confirm it is off (lamp: write coil 0 off: no reply)"
    assert lamp["data"] == {"off": False, "error": "lamp: write coil 0 off: no reply"}


def test_a_camera_error_in_the_calibration_names_the_part_and_stops_every_axis(table, tmp_path):
    hardware = rig(table, camera_fail=lambda seen, t: seen == "flat")
    with pytest.raises(SessionFault) as caught:
        run(hardware, tmp_path)
    assert str(caught.value).startswith("capture failed during Expose in the calibration: fake camera: no frame "
                                        "of 0.128 s. Stopped theta_i at 0.00 deg, theta_o at 30.00 deg, phi_o at "
                                        "180.00 deg; the lamp is off. 0 of 2 samples are safe")
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1] and hardware.lamp.is_on is False
    with Journal.open(tmp_path / "session.sqlite") as journal:
        last = journal.steps()[-1]
    assert (last["kind"], last["detail"]["file"], last["status"]) == ("Expose", "calibration/flat_e3_0.dng", "failed")


def test_an_error_the_plan_raises_is_charged_to_the_step_before_it(table, tmp_path):
    hardware = rig(table)
    hardware.lamp.photodiode = lambda: 0.0  # the monitor photodiode reads nothing
    with pytest.raises(SessionFault) as caught:
        run(hardware, tmp_path / "a")
    assert str(caught.value).startswith("capture failed during Expose in the calibration: ")
    assert "white_e2.dng: the monitor photodiode reads 0.0: is the lamp on?" in str(caught.value)
    # with the calibration kept, a sample's frame: its plan index and angles
    with pytest.raises(SessionFault):
        run(rig(table, theta_o={"fail_on_move": 3}), tmp_path / "b")
    hardware = rig(table)
    hardware.lamp.photodiode = lambda: 0.0
    with pytest.raises(SessionFault) as caught:
        run(hardware, tmp_path / "b")
    assert str(caught.value).startswith("capture failed at plan sample 1 (theta_i 0.0 deg, theta_o 35.0 deg): ")
    assert "sample_0001_e2.dng: the monitor photodiode reads 0.0: is the lamp on?" in str(caught.value)


def test_an_interrupt_during_a_step_stops_every_axis_and_marks_it_interrupted(table, tmp_path):
    hardware = rig(table, theta_i={"interrupt_on_move": 3})
    with pytest.raises(SessionInterrupted) as caught:
        run(hardware, tmp_path)
    assert str(caught.value).startswith("interrupted by SIGINT at plan sample 1. Stopped theta_i at 0.00 deg, "
                                        "theta_o at 30.00 deg, phi_o at 180.00 deg; the lamp is off. 1 of 2 samples")
    assert str(caught.value).endswith("Run the same command with --resume to continue")
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1] and hardware.lamp.is_on is False
    with Journal.open(tmp_path / "session.sqlite") as journal:
        last, events, done = journal.steps()[-1], journal.events(), journal.done_indices()
    assert (last["kind"], last["plan_index"], last["status"]) == ("Move", 1, "interrupted")
    assert [e["kind"] for e in events][-3:] == ["interrupted", "stop", "lamp"] and done == {0}


class FakeSimulation:
    """A simulated rig's drills and state (the contract's Simulation): one drill due at sample 1,
    which strikes as soon as it is armed; the state is the fake clock's time and the axes' degrees."""

    DRILL = {"drill": 0, "axis": "theta_o", "kind": "stall", "at_sample": 1}

    def __init__(self, hardware) -> None:
        self.hw, self.calls, self.armed, self.retired = hardware, [], False, []

    def arm_faults(self, sample_index: int) -> list[dict]:
        self.calls.append(("arm", sample_index))
        if sample_index >= 1 and not self.armed and self.DRILL not in self.retired:
            self.armed = True
            return [dict(self.DRILL)]
        return []

    def struck_faults(self) -> list[dict]:
        return [dict(self.DRILL)] if self.armed else []

    def retire_faults(self, drills) -> None:
        self.retired += list(drills)

    def checkpoint(self) -> dict:
        return {"t": self.hw.clock.t, "deg": {name: a.deg for name, a in self.hw.axes.items()}}

    def restore(self, state: dict) -> None:
        self.calls.append(("restore", state))
        self.hw.clock.t = state["t"]
        for name, deg in state["deg"].items():
            self.hw.axes[name].deg = deg


def test_drills_are_armed_before_each_sample_and_a_resume_restores_the_journaled_state(table, tmp_path):
    first = rig(table, theta_o={"fail_on_move": 3})  # sample 1's move fails, as the drill would make it
    first.simulation = FakeSimulation(first)
    with pytest.raises(SessionFault):
        run(first, tmp_path)
    assert first.simulation.calls == [("arm", 0), ("arm", 1)]
    with Journal.open(tmp_path / "session.sqlite") as journal:
        state = journal.step_result("Commit", 0)["sim_state"]
        drills = [(e["message"], e["data"]["state"]) for e in journal.events() if e["kind"] == "drill"]
    # journaled with sample 0: the clock after the 18 s move to the white pose, the axes at sample 0's joints
    assert state == {"t": 18.0, "deg": {"theta_i": 0.0, "theta_o": 30.0, "phi_o": 180.0}}
    assert drills == [("drill armed: stall on theta_o when it next moves (sim.faults[0], at_sample 1)", "armed"),
                      ("drill struck: stall on theta_o", "struck")]

    second = rig(table)
    second.simulation = FakeSimulation(second)
    stats, steps, events, samples = run(second, tmp_path)
    assert second.simulation.retired == [FakeSimulation.DRILL]  # struck before: never armed again
    assert second.simulation.calls == [("restore", state), ("arm", 1)]  # before sample 1's move, in that order
    assert [r.plan_index for r in samples] == [0, 1] and stats.captured == 1
    [restored] = [e for e in events if e["kind"] == "simulation"]
    assert restored["message"] == "simulated rig restored as journaled before plan sample 1"
    assert [e["data"]["state"] for e in events if e["kind"] == "drill"] == ["armed", "struck"]


def hand_plan():
    """A short hand command's plan: move two axes, lamp on and off; returns the joints reached."""
    from goniofrost.capture.steps import LampOff, LampOn, Move

    reached = yield Move(None, (("theta_i", 10.0), ("theta_o", 40.0)))
    yield LampOn()
    yield LampOff()
    return reached.joints


def test_a_short_plan_runs_on_the_engine_core_without_a_journal(table, tmp_path):
    from goniofrost.capture.plan_runner import PlanRunner

    hardware = rig(table)
    runner = PlanRunner(hardware, tmp_path, program="rig move")
    assert runner.execute_plan(hand_plan()) == {"theta_i": 10.0, "theta_o": 40.0}
    assert (runner.run_end.status, runner.run_end.reason, runner.run_start.program) == \
        (RunStatus.FINISHED, "rig move finished", "rig move")
    assert list(tmp_path.iterdir()) == [] and all(a.stops == 0 for a in hardware.axes.values())
    # a fault: every axis stopped and confirmed, the lamp off, the same words as a capture's
    hardware = rig(table, theta_o={"fail_on_move": 1})
    runner = PlanRunner(hardware, tmp_path, program="rig move")
    with pytest.raises(SessionFault) as caught:
        runner.execute_plan(hand_plan())
    assert str(caught.value).startswith("device fault during Move: theta_o: move to 40 deg: device fault: alarm "
                                        "(reply: 0.0). Stopped theta_i at 10.00 deg, ")
    assert str(caught.value).endswith("the lamp is off. Nothing was journaled. Fix the cause, then run the same "
                                      "command again")
    assert runner.run_end.status is RunStatus.FAULT and runner.run_end.axis == "theta_o"
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1] and hardware.lamp.is_on is False


def test_a_queues_white_reference_re_measured_counts_as_calibration_time():
    from goniofrost.capture.engine import SessionStats

    # a queue's second sample re-measures only the white reference (phase "white_reference"): its
    # summary read "this run: calibration 0.0 s"
    assert SessionStats(phase_s={"white_reference": 0.25, "samples": 9.0}).calibration_s == 0.25
    # the lamp drifted: the re-measured white reference and the full calibration after it
    assert SessionStats(phase_s={"white_reference": 0.25, "calibration": 4.5}).calibration_s == 4.75
    assert SessionStats(phase_s={"calibration": 4.5, "samples": 9.0}).calibration_s == 4.5


def test_the_journal_holds_exactly_the_records_the_run_emits(table, tmp_path):
    """The engine core writes nothing itself: its journal is a subscriber (RunJournal) whose runs,
    steps and events are the records another subscriber is handed, field for field."""
    from goniofrost.capture.plan_runner import PlanRunner
    from goniofrost.capture.records import Event, RunEnd, RunStart, StepDone, StepStarting

    journal = Journal.create(tmp_path / "session.sqlite", {"plan": "test"})
    seen = []
    runner = PlanRunner(rig(table), tmp_path, journal=journal, program="rig move")
    runner.subscribe(seen.append)
    runner.execute_plan(hand_plan())
    kinds = [type(r).__name__ for r in seen if not isinstance(r, (StepStarting, StepDone))]
    assert kinds == ["RunStart", "Event", "SafePoint", "SafePoint", "SafePoint", "PlanEnded", "RunEnd", "Event"]
    start, end = next(r for r in seen if isinstance(r, RunStart)), next(r for r in seen if isinstance(r, RunEnd))
    assert journal.runs() == [(start, end)] and (start.run, start.program, end.status) == (1, "rig move",
                                                                                            RunStatus.FINISHED)
    events = [(e["kind"], e["message"], e["data"]) for e in journal.events()]
    assert events == [(r.kind, r.message, r.data) for r in seen if isinstance(r, Event)] == [
        (EventKind.SESSION, "rig move run 1 started with 0 of 0 samples done", {"run": 1}),
        (EventKind.SESSION, "rig move finished", {"status": "finished"})]
    assert [(s["kind"], s["status"]) for s in journal.steps()] == [("Move", "done"), ("LampOn", "done"),
                                                                   ("LampOff", "done")]
    journal.close()


def test_a_subscriber_s_error_is_a_warning_and_a_required_one_s_stops_the_run_safely(table, tmp_path):
    from goniofrost.capture.plan_runner import PlanRunner, StepDone, SubscriberWarning

    hardware = rig(table)
    runner = PlanRunner(hardware, tmp_path, program="rig move")
    seen = []
    runner.subscribe(lambda record: isinstance(record, StepDone) and 1 / 0)  # a display that breaks: the run goes on
    runner.subscribe(lambda record: seen.append((type(record.step).__name__, record.summary))
                     if isinstance(record, StepDone) else None)
    with pytest.warns(SubscriberWarning, match=r"^Move: a subscriber failed: division by zero$"):
        assert runner.execute_plan(hand_plan()) == {"theta_i": 10.0, "theta_o": 40.0}
    assert [kind for kind, _ in seen] == ["Move", "LampOn", "LampOff"]
    assert seen[0][1]["joints"] == {"theta_i": 10.0, "theta_o": 40.0} and seen[2][1] == {}
    assert runner.run_end.status is RunStatus.FINISHED
    # a required subscriber (a file the session keeps) fails: every axis stopped, the lamp off
    hardware = rig(table)
    runner = PlanRunner(hardware, tmp_path, program="rig move")
    full = OSError(28, "No space left on device", "samples.csv")
    runner.subscribe(lambda record: isinstance(record, StepDone) and (_ for _ in ()).throw(full), required=True)
    with pytest.raises(SessionFault) as caught:
        runner.execute_plan(hand_plan())
    assert str(caught.value).startswith("rig move failed during Move: samples.csv: cannot write: no space left on the "
                                        "device. Stopped theta_i at 10.00 deg, ")
    assert runner.run_end.status is RunStatus.REFUSED
    assert [a.stops for a in hardware.axes.values()] == [1, 1, 1] and hardware.lamp.is_on is False
