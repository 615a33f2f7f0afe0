"""Fault drills from the rig file (``sim: faults:``): ``SimulatedRig.arm_faults(sample_index)`` arms
each drill once its plan sample is reached, and the fault strikes when that axis next moves, once:
every kind on every protocol raises the driver's typed error."""
from __future__ import annotations

import logging
from pathlib import Path

import pytest
import yaml

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, ProtocolError
from drivers.rig_devices import axis_from_spec, connect_axis
from goniofrost.rig.hardware import open_hardware
from goniofrost.rig.simulated import simulated_devices
from goniofrost.capture.plan_runner import PlanRunner, SessionFault
from goniofrost.capture.records import SafePoint
from goniofrost.capture.records import RunStatus
from goniofrost.rig.file import section_validators
from goniofrost.capture.steps import Home, LampOff, LampOn, Move
from goniofrost.core.errors import ConfigError
from planner.rig import rig_from_mapping
from sim.faults import FAULT_KINDS
from sim.rig import SimulatedRig
from goniofrost.rig.hardware import SimOptions

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # injected faults make pymodbus log errors

# axis (protocol) -> where it moves in the drill
TARGETS = {"camera_arm": 60.0, "sample_yaw": 40.0, "sample_tilt": 20.0}
# (axis, kind) -> the typed error the driver raises; as in the protocol tests' fault matrices
ERRORS = {
    "camera_arm": {"no_reply": DeviceTimeout, "bad_checksum": ProtocolError, "drop_byte": ProtocolError,
                   "alarm": DeviceFault, "stall": DeviceFault, "disconnect": DeviceTimeout},
    "sample_yaw": {"no_reply": DeviceTimeout, "bad_checksum": ChecksumError, "drop_byte": ProtocolError,
                   "alarm": DeviceFault, "stall": DeviceFault, "disconnect": DeviceTimeout},
    "sample_tilt": {"no_reply": DeviceTimeout, "bad_checksum": ProtocolError, "drop_byte": DeviceTimeout,
                    "alarm": DeviceFault, "stall": DeviceFault, "disconnect": DeviceTimeout},
}


def drill_rig(*faults):
    """The checked simulated rig with these (axis, kind, at_sample) drills."""
    raw = yaml.safe_load(RIG.read_text())
    raw["sim"]["faults"] = [dict(zip(("axis", "kind", "at_sample"), f)) for f in faults]
    return rig_from_mapping(raw, str(RIG), section_validators())


def connected_axis(rig: SimulatedRig, name: str):
    """The real driver of one simulated axis (homed, enabled), detecting a stall after 0.3 s."""
    spec = rig.resolved_rig().axes[name]
    axis = axis_from_spec(spec, stall_s=0.3)
    connect_axis(axis, spec.driver)
    axis.enable()
    axis.home().wait()  # the SMC100 accepts moves only once referenced
    return axis


def test_a_drill_is_armed_at_its_sample_and_strikes_on_the_next_move_once():
    with SimulatedRig(drill_rig(("sample_yaw", "stall", 3)), speedup=20) as rig:
        device, axis = rig.device("sample_yaw"), connected_axis(rig, "sample_yaw")
        try:
            assert rig.arm_faults(2) == [] and device.armed == []
            assert axis.move_to(20.0).wait() == pytest.approx(20.0, abs=0.1)
            drill = {"drill": 0, "axis": "sample_yaw", "kind": "stall", "at_sample": 3}
            assert rig.arm_faults(3) == [drill]
            assert device.armed == ["stall"] and device.faults == set()  # waiting for the move
            assert axis.position() == pytest.approx(20.0, abs=0.1)     # reading is no move
            assert rig.struck_faults() == []
            with pytest.raises(DeviceFault, match="stall"):
                axis.move_to(40.0).wait()
            assert device.armed == [] and rig.arm_faults(4) == []      # once
            assert rig.struck_faults() == [drill]
        finally:
            axis.close()


def test_drills_of_earlier_samples_are_armed_together():
    with SimulatedRig(drill_rig(("sample_tilt", "alarm", 1), ("camera_arm", "stall", 2),
                                ("camera_arm", "no_reply", 7)), speedup=20) as rig:
        armed = rig.arm_faults(5)  # e.g. the first sample run is 5
        assert [(f["axis"], f["kind"]) for f in armed] == [("sample_tilt", "alarm"), ("camera_arm", "stall")]
        assert rig.device("camera_arm").armed == ["stall"] and rig.device("sample_tilt").armed == ["alarm"]
        assert [f["kind"] for f in rig.arm_faults(7)] == ["no_reply"]


def test_a_retired_drill_is_never_armed_and_a_changed_one_is_not_retired():
    faults = (("sample_tilt", "alarm", 1), ("camera_arm", "stall", 2), ("sample_yaw", "no_reply", 2))
    with SimulatedRig(drill_rig(*faults), speedup=20) as rig:
        rig.retire_faults([{"drill": 0, "axis": "sample_tilt", "kind": "alarm", "at_sample": 1},   # struck before
                           {"drill": 1, "axis": "camera_arm", "kind": "alarm", "at_sample": 2}])   # rig file changed
        assert [f["drill"] for f in rig.arm_faults(5)] == [1, 2]
        assert rig.device("sample_tilt").armed == [] and rig.device("camera_arm").armed == ["stall"]


def test_a_checkpoint_restores_positions_and_nominal_time():
    with SimulatedRig(drill_rig(), speedup=20) as rig:
        axis = connected_axis(rig, "camera_arm")
        try:
            axis.move_to(60.0).wait()
            state = rig.checkpoint()
            assert state["positions"]["camera_arm"] == 6000.0 and state["nominal_time"] > 0
            axis.move_to(120.0).wait()
            assert rig.checkpoint() != state
            rig.restore(state)
            assert rig.checkpoint() == state and axis.position() == pytest.approx(60.0)
            assert not axis.is_moving()
        finally:
            axis.close()


@pytest.mark.parametrize("name", list(TARGETS))
@pytest.mark.parametrize("kind", FAULT_KINDS)
def test_every_kind_strikes_on_every_protocol(name, kind):
    with SimulatedRig(drill_rig((name, kind, 0)), speedup=20) as rig:
        axis = connected_axis(rig, name)
        try:
            rig.arm_faults(0)
            with pytest.raises(ERRORS[name][kind]) as err:
                axis.move_to(TARGETS[name]).wait()
            assert err.value.axis == name
        finally:
            axis.close()


def test_a_drill_on_an_axis_the_rig_does_not_have_is_refused():
    with pytest.raises(ConfigError, match=r"sim.faults\[0\].axis: expected one of the rig's axes "
                                          r"\['camera_arm', 'sample_tilt', 'sample_yaw'\], found 'sample_pitch'"):
        SimulatedRig(drill_rig(("sample_pitch", "stall", 0)))


@pytest.mark.parametrize("name", list(TARGETS))
def test_confirm_stopped_reads_past_an_alarm_and_does_not_confirm_a_motor_that_still_moves(name):
    with SimulatedRig(drill_rig(), speedup=20) as rig:
        device, axis = rig.device(name), connected_axis(rig, name)
        try:
            device.inject_fault("stall")  # the device reports motion for ever
            axis.move_to(TARGETS[name])
            with pytest.raises(DeviceTimeout, match="still reports motion 0.3 s after the stop"):
                axis.confirm_stopped(timeout_s=0.3)
            axis.stop()
            assert axis.confirm_stopped() == pytest.approx(device.true_position_deg(), abs=0.1)
            device.inject_fault("clear")
            device.inject_fault("alarm")  # the drive shuts down: every status carries the fault
            with pytest.raises(DeviceFault):
                axis.is_moving()
            axis.stop()
            assert axis.confirm_stopped() == pytest.approx(device.true_position_deg(), abs=0.1)
        finally:
            axis.close()


# ----- one stop per axis per exit: the engine's stop on a fault, the rig's release on any exit ------
def _stop_commands(twins: dict) -> dict[str, int]:
    """The stop commands each twin received: the drive's STOP input bit set, the SMC100's ST, the
    servo's Goal Position writes after its home's (``_run`` leaves it at home: its move sends
    nothing, so every later write is a stop, goal := present)."""
    from drivers.dxl_protocol import CONTROL_TABLE, Instruction
    from drivers.modbus_map import InputBit, from_registers

    drive = twins["camera_arm"]
    stop_bit = 1 << drive.map.input_bits[InputBit.STOP]
    goal = CONTROL_TABLE["goal_position"].addr.to_bytes(2, "little")
    goal_writes = sum(p.instruction == Instruction.WRITE and p.params[:2] == goal for p in twins["sample_yaw"].received)
    return {"camera_arm": sum(address == drive.map.input_command and
                              from_registers(values[:2], drive.word_order, signed=False) & stop_bit != 0
                              for address, values in drive.writes),
            "sample_yaw": goal_writes - 1,
            "sample_tilt": sum(line.strip().upper().endswith(b"ST") for line in twins["sample_tilt"].received)}


def _drilled(hardware, folder) -> PlanRunner:
    """A runner that arms the rig's drills before each plan sample, as a capture does."""
    runner = PlanRunner(hardware, folder, samples_only_safe=True)
    runner.subscribe(lambda record: isinstance(record, SafePoint) and hardware.simulation.arm_faults(record.step.index),
                     required=True)
    return runner


def _run(rig_spec, folder):
    """Home, lamp on, one plan sample's move, lamp off on the simulated rig; (stop commands per
    twin, lamp on after the release, the run's end)."""
    def plan():
        yield Home(tuple(TARGETS))
        yield LampOn()
        yield Move(0, (("camera_arm", 60.0), ("sample_yaw", 0.0), ("sample_tilt", 20.0)))  # the servo stays home
        yield LampOff()

    with open_hardware(rig_spec, simulated_devices, sim=SimOptions(speedup=20)) as hardware:
        twins = {name: hardware.simulation.device(name) for name in TARGETS}  # kept past the release
        lamp = hardware.simulation.lamp_model
        runner = _drilled(hardware, folder)
        try:
            runner.execute_plan(plan())
        except SessionFault:
            pass
    return _stop_commands(twins), lamp.is_on, runner.run_end


def test_every_axis_is_stopped_once_on_a_normal_exit_and_on_a_fault_exit(tmp_path):
    # a normal exit: the release stops every axis
    stops, lamp_on, end = _run(drill_rig(), tmp_path / "a")
    assert end.status is RunStatus.FINISHED and stops == {name: 1 for name in TARGETS} and lamp_on is False
    # a fault exit: the engine stops every axis (the alarmed drive also stopped itself at the alarm);
    # the release finds each confirmed at rest, and stops none again
    stops, lamp_on, end = _run(drill_rig(("camera_arm", "alarm", 0)), tmp_path / "b")
    assert end.status is RunStatus.FAULT and [s.confirmed for s in end.stops] == [True] * 3
    assert stops == {"camera_arm": 2, "sample_yaw": 1, "sample_tilt": 1} and lamp_on is False
    # a stop that could not be confirmed (the stage no longer answers): the release tries it again
    stops, lamp_on, end = _run(drill_rig(("sample_tilt", "no_reply", 0)), tmp_path / "c")
    assert [(s.axis, s.confirmed) for s in end.stops] == [("camera_arm", True), ("sample_yaw", True),
                                                           ("sample_tilt", False)]
    assert stops == {"camera_arm": 1, "sample_yaw": 1, "sample_tilt": 3} and lamp_on is False
