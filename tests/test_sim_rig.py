"""The simulated rig: three axes moving at once through the real drivers, the lamp, a fault during a
three-axis move, and the "done when" of issue 6: ``goniofrost sim`` in a subprocess driven by the
official clients only (dynamixel-sdk, a plain serial terminal, a pymodbus client)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import TWIN_REPLY_TIMEOUT_MS
import serial
import yaml
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler
from sdk_retry import sdk_call
from pymodbus.client import ModbusTcpClient

from drivers.errors import DeviceFault
from goniofrost.rig.stop import stop_axes
from drivers.rig_devices import RigDevices
from goniofrost.rig.file import section_validators
from planner.rig import rig_from_mapping
from sim.rig import SimulatedRig

ROOT = Path(__file__).resolve().parents[1]
RIG = ROOT / "config" / "rigs" / "sim.yaml"


@pytest.fixture(scope="module")
def raw_rig():
    with open(RIG, encoding="utf-8") as f:
        return yaml.safe_load(f)


def checked(raw):
    """The typed rig spec of a rig mapping, every section checked."""
    return rig_from_mapping(raw, str(RIG), section_validators())


def test_endpoints_and_resolved_sections(raw_rig):
    with SimulatedRig(checked(raw_rig), speedup=50) as rig:
        ep = rig.endpoints
        assert set(ep) == {"camera_arm", "sample_yaw", "sample_tilt", "lamp"}
        assert ep["sample_yaw"] == {"protocol": "dynamixel", "endpoint": ep["sample_yaw"]["endpoint"],
                                    "id": 1, "baud": 57600}
        assert ep["sample_tilt"]["protocol"] == "smc100" and ep["sample_tilt"]["address"] == 1
        assert ep["camera_arm"]["protocol"] == "modbus-tcp" and ep["camera_arm"]["endpoint"].startswith("127.0.0.1:")
        assert os.path.exists(ep["sample_yaw"]["endpoint"]) and os.path.exists(ep["sample_tilt"]["endpoint"])
        resolved = rig.resolved_rig()
        host, port = ep["camera_arm"]["endpoint"].split(":")
        arm = resolved.axes["camera_arm"].driver
        assert (arm["host"], arm["port"]) == (host, int(port))
        assert resolved.axes["sample_yaw"].driver["port"] == ep["sample_yaw"]["endpoint"]
        # the tests' slow host (conftest): every twin's driver waits TWIN_REPLY_TIMEOUT_MS
        assert {name: a.driver["reply_timeout_ms"] for name, a in resolved.axes.items()} == \
            {name: TWIN_REPLY_TIMEOUT_MS for name in ("camera_arm", "sample_yaw", "sample_tilt")}
        assert rig.rig.axes["sample_yaw"].driver["port"] == "sim"  # the rig given is untouched
        assert type(resolved) is type(rig.rig) and resolved.geometry == rig.rig.geometry
        assert rig.true_joints_deg() == {"camera_arm": 90.0, "sample_yaw": 0.0, "sample_tilt": 0.0}


def test_twins_reply_timeouts_without_the_slow_host_setting_and_with_a_drill(raw_rig, monkeypatch):
    """Without the slow-host setting a Dynamixel twin's driver waits 300 ms (it answers from a thread
    of this process, not a real bus's 100 ms), the others their drivers' defaults; with it, an axis
    drilled to fall silent or to damage its replies keeps that timeout, so its drill times out as
    promptly, while an axis drilled to stall (it still answers) gets the slow host's."""
    import copy

    from sim.rig import SLOW_HOST_ENV

    monkeypatch.delenv(SLOW_HOST_ENV)
    with SimulatedRig(checked(raw_rig), speedup=50) as rig:
        assert {name: a.driver.get("reply_timeout_ms") for name, a in rig.resolved_rig().axes.items()} == \
            {"camera_arm": None, "sample_yaw": 300.0, "sample_tilt": None}
    monkeypatch.setenv(SLOW_HOST_ENV, "2500")
    raw = copy.deepcopy(raw_rig)
    raw.setdefault("sim", {})["faults"] = [{"axis": "sample_yaw", "kind": "no_reply", "at_sample": 3},
                                           {"axis": "camera_arm", "kind": "stall", "at_sample": 1},
                                           {"axis": "sample_tilt", "kind": "bad_checksum", "at_sample": 2}]
    with SimulatedRig(checked(raw), speedup=50) as rig:
        assert {name: a.driver.get("reply_timeout_ms") for name, a in rig.resolved_rig().axes.items()} == \
            {"camera_arm": 2500.0, "sample_yaw": 300.0, "sample_tilt": None}


def test_a_rig_file_s_own_reply_timeout_wins_over_the_twin_s_default(raw_rig):
    import copy

    raw = copy.deepcopy(raw_rig)
    raw["axes"]["sample_yaw"]["driver"]["reply_timeout_ms"] = 150
    with SimulatedRig(checked(raw), speedup=50) as rig:
        assert rig.resolved_rig().axes["sample_yaw"].driver["reply_timeout_ms"] == 150


def test_three_axes_move_at_once(raw_rig):
    targets = {"camera_arm": 40.0, "sample_yaw": -120.0, "sample_tilt": 35.0}
    with SimulatedRig(checked(raw_rig), speedup=20) as rig:
        with RigDevices.from_rig(rig.resolved_rig()) as devices:
            for status in [a.home() for a in devices.axes.values()]:
                status.wait()
            statuses = {n: devices.axes[n].move_to(t) for n, t in targets.items()}
            moving = {n: rig.device(n).motion.is_moving() for n in targets}
            finals = {n: s.wait() for n, s in statuses.items()}
            truth = rig.true_joints_deg()
    assert moving == {n: True for n in targets}  # all three in motion together
    for name, target in targets.items():
        tol = raw_rig["axes"][name]["tolerance_deg"]
        assert finals[name] == pytest.approx(target, abs=tol)
        assert truth[name] == pytest.approx(target, abs=tol)


def test_lamp_on_the_modbus_drive(raw_rig):
    with SimulatedRig(checked(raw_rig), speedup=20) as rig:
        with RigDevices.from_rig(rig.resolved_rig()) as devices:
            assert devices.lamp.is_on() is False and devices.lamp.photodiode() == 0.0
            devices.lamp.on()
            assert rig.lamp_model.is_on and devices.lamp.is_on()
            assert devices.lamp.photodiode() == pytest.approx(rig.lamp_model.relative_intensity(), abs=0.01)


def test_fault_on_one_axis_during_a_three_axis_move_stops_all(raw_rig):
    with SimulatedRig(checked(raw_rig), speedup=5) as rig:
        devices = RigDevices.from_rig(rig.resolved_rig())
        devices.connect_all()
        try:
            for status in [a.home() for a in devices.axes.values()]:
                status.wait()  # the SMC100 accepts moves only once referenced
            statuses = {n: devices.axes[n].move_to(t)
                        for n, t in {"camera_arm": 160.0, "sample_yaw": 170.0, "sample_tilt": 70.0}.items()}
            rig.clock.sleep(0.3)
            rig.device("sample_yaw").inject_fault("alarm")
            with pytest.raises(DeviceFault, match="sample_yaw.*overload"):
                statuses["sample_yaw"].wait()
            assert all(s.confirmed for s in stop_axes(devices.axes))  # the one stop path
            deadline = time.monotonic() + 2.0
            while any(rig.device(n).motion.is_moving() for n in statuses) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert not any(rig.device(n).motion.is_moving() for n in statuses)
            assert rig.true_joints_deg()["camera_arm"] < 150.0  # stopped on the way
        finally:
            devices.close_all()


# ----- "done when": goniofrost sim + official clients, no goniofrost code in the clients ------------
@pytest.fixture(scope="module")
def sim_process():
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "sim", "--rig", str(RIG), "--speedup", "20"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = []
    reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout=20)
    if not line or not line[0].strip():
        proc.kill()
        pytest.fail(f"goniofrost sim printed no endpoints: {proc.stderr.read()}")
    yield proc, json.loads(line[0])
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_dynamixel_sdk_pings_moves_and_reads_the_yaw_servo(sim_process):
    _, ep = sim_process
    yaw = ep["sample_yaw"]
    port, ph = PortHandler(yaw["endpoint"]), PacketHandler(2.0)
    assert port.openPort() and port.setBaudRate(yaw["baud"])
    try:
        model, result, error = sdk_call(ph.ping, port, yaw["id"])
        assert result == COMM_SUCCESS and model in (1020, 1030, 1120, 1130)
        assert sdk_call(ph.write1ByteTxRx, port, yaw["id"], 64, 1) == (COMM_SUCCESS, 0)
        assert sdk_call(ph.write4ByteTxRx, port, yaw["id"], 116, 1024) == (COMM_SUCCESS, 0)  # 90 deg
        deadline = time.monotonic() + 10
        while sdk_call(ph.read1ByteTxRx, port, yaw["id"], 122)[0] and time.monotonic() < deadline:
            time.sleep(0.02)
        assert sdk_call(ph.read4ByteTxRx, port, yaw["id"], 132)[:2] == (1024, COMM_SUCCESS)
    finally:
        port.closePort()


def _ask(term: serial.Serial, line: str) -> str:
    term.reset_input_buffer()
    term.write(line.encode() + b"\r\n")
    return term.readline().decode().strip()


def test_serial_terminal_homes_and_moves_the_smc100(sim_process):
    _, ep = sim_process
    tilt = ep["sample_tilt"]
    with serial.Serial(tilt["endpoint"], tilt["baud"], timeout=1.0, xonxoff=True) as term:
        assert _ask(term, "1TS") == "1TS00000A"  # NOT REFERENCED after power-up
        term.write(b"1OR\r\n")
        deadline = time.monotonic() + 10
        while _ask(term, "1TS")[-2:] != "32" and time.monotonic() < deadline:  # READY from HOMING
            time.sleep(0.02)
        term.write(b"1PA12.5\r\n")
        while _ask(term, "1TS")[-2:] != "33" and time.monotonic() < deadline:  # READY from MOVING
            time.sleep(0.02)
        reply = _ask(term, "1TP")
    assert reply.startswith("1TP") and float(reply[3:]) == pytest.approx(12.5)


def test_pymodbus_client_moves_the_camera_arm_through_the_az_registers(sim_process):
    _, ep = sim_process
    arm = ep["camera_arm"]
    host, port = arm["endpoint"].split(":")
    client = ModbusTcpClient(host, port=int(port), timeout=2, retries=1)
    assert client.connect()
    try:
        def int32(v):
            return client.convert_to_registers(v, client.DATATYPE.INT32, word_order="big")
        # direct data operation: No. 0, absolute, 6000 steps (60 deg), 3000 Hz, rates 6000, 100 %, trigger
        values = [0, 0, *int32(1), *int32(6000), *int32(3000), *int32(6000), *int32(6000), *int32(1000), *int32(1)]
        assert not client.write_registers(0x0058, values, device_id=arm["id"]).isError()
        deadline, position = time.monotonic() + 10, None
        while time.monotonic() < deadline:
            rr = client.read_holding_registers(0x0120, count=2, device_id=arm["id"])
            assert not rr.isError()
            position = client.convert_from_registers(rr.registers, client.DATATYPE.INT32, word_order="big")
            if position == 6000:
                break
            time.sleep(0.02)
        assert position == 6000
    finally:
        client.close()


def test_sim_process_stops_cleanly_on_sigterm(sim_process):
    proc, ep = sim_process
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=10) == 0
    host, port = ep["camera_arm"]["endpoint"].split(":")
    client = ModbusTcpClient(host, port=int(port), timeout=1, retries=0)
    assert not client.connect()  # the Modbus port was released


def test_modbus_rtu_axis_on_a_pty(raw_rig):
    rtu = {**raw_rig, "axes": {**raw_rig["axes"], "camera_arm": {
        **raw_rig["axes"]["camera_arm"],
        "driver": {"protocol": "modbus-rtu", "port": "sim", "baud": 115200, "parity": "N",
                   "device_id": 1, "steps_per_deg": 100.0}}}}
    with SimulatedRig(checked(rtu), speedup=20) as rig:
        assert rig.endpoints["camera_arm"]["protocol"] == "modbus-rtu"
        assert rig.endpoints["camera_arm"]["endpoint"].startswith("/dev/pts/")
        with RigDevices.from_rig(rig.resolved_rig()) as devices:
            assert devices.axes["camera_arm"].move_to(45.0).wait() == pytest.approx(45.0, abs=0.02)
            assert rig.true_joints_deg()["camera_arm"] == pytest.approx(45.0, abs=0.02)


def test_sim_command_bad_input_is_one_line_and_status_2(tmp_path, capsys):
    from goniofrost.app.cli import main
    assert main(["sim", "--rig", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("goniofrost sim: error: ") and "missing.yaml" in err and "\n" not in err
    assert main(["sim", "--rig", str(RIG), "--speedup", "0"]) == 2
    assert capsys.readouterr().err.strip() == \
        "goniofrost sim: error: command line: --speedup: expected a number > 0, found 0.0"
