"""Modbus drive: the register map as data, exact frames (direct-data write, exception replies over
TCP and RTU), the official pymodbus client and the driver against the simulated AZ drive, and
every injected fault -> the documented error and a stopped motor."""
from __future__ import annotations

import logging
import socket
import time
from pathlib import Path

import pytest
import serial
import yaml
from pymodbus.client import ModbusTcpClient

from drivers.axis import AxisConfig
from drivers.config import validate_driver_section
from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, ExceptionReply, ProtocolError
from drivers.modbus_drive import ModbusAxis
from drivers.modbus_protocol import modbus_crc
from drivers.modbus_map import ORIENTAL_AZ, direct_data_registers, from_registers, resolve_map, to_registers
from goniofrost.core.errors import ConfigError
from sim.clock import SimClock
from sim.modbus_drive import SimulatedModbusDrive

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # injected faults make pymodbus log errors


@pytest.fixture
def drive(request):
    transport, speedup = getattr(request, "param", ("tcp", 40.0))
    dev = SimulatedModbusDrive(SimClock(speedup), transport=transport, position_deg=90.0)
    dev.start()
    yield dev
    dev.stop()


def make_axis(dev: SimulatedModbusDrive, register_map="oriental-az", word_order="big") -> ModbusAxis:
    cfg = AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, home_deg=90.0, tolerance_deg=0.02,
                     retries=1, stall_s=0.3)
    if dev.transport == "rtu":
        ax = ModbusAxis(cfg, serial_port=dev.endpoint["endpoint"], parity="N", timeout_s=0.1,
                        register_map=register_map, word_order=word_order)
    else:
        ax = ModbusAxis(cfg, host="127.0.0.1", port=dev.port, timeout_s=0.1,
                        register_map=register_map, word_order=word_order)
    ax.connect()
    return ax


def wait_for(predicate, timeout_s: float = 3.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < t_end, "condition not reached in time"
        time.sleep(0.005)


# ----- the register map as data ------------------------------------------------------------------
def test_32_bit_values_follow_the_az_word_order_and_match_pymodbus():
    assert to_registers(-1000) == [0xFFFF, 0xFC18]  # PROTOCOLS.md: -1000 -> FFFF FC18
    assert to_registers(-1000, "little") == [0xFC18, 0xFFFF]
    for order in ("big", "little"):
        for value in (-10, 0, 1, 12000, -(1 << 31), (1 << 31) - 1):
            words = to_registers(value, order)
            assert words == ModbusTcpClient.convert_to_registers(value, ModbusTcpClient.DATATYPE.INT32,
                                                                 word_order=order)
            assert from_registers(words, order) == value
    assert from_registers([0xFFFF, 0xFFFF], signed=False) == 0xFFFFFFFF


def test_named_and_inline_maps():
    assert resolve_map("oriental-az") is ORIENTAL_AZ
    assert (ORIENTAL_AZ.direct_data, ORIENTAL_AZ.feedback_position, ORIENTAL_AZ.output_bits["alm_a"]) == (0x58, 0x120, 7)
    inline = resolve_map({"base": "oriental-az", "feedback_position": 0x0204, "output_bits": {"move": 12}})
    assert (inline.feedback_position, inline.output_bits["move"], inline.output_bits["ready"]) == (0x204, 12, 5)
    assert inline.direct_data == 0x58


@pytest.mark.parametrize("spec, keypath, found", [
    ("yaskawa", "driver.register_map", "yaskawa"),
    ({"base": "oriental-az", "feedback": 1}, "driver.register_map.feedback", "feedback"),
    ({"feedback_position": 0x120}, "driver.register_map.direct_data", None),
    ({"base": "oriental-az", "alarm_code": 0x10000}, "driver.register_map.alarm_code", 0x10000),
    ({"base": "oriental-az", "input_bits": {"start": 16}}, "driver.register_map.input_bits.start", 16),
])
def test_bad_maps_name_the_key(spec, keypath, found):
    with pytest.raises(ConfigError) as err:
        resolve_map(spec, "rig.yaml", "driver.register_map")
    assert (err.value.keypath, err.value.found) == (keypath, found)


def test_rig_file_sections_validate_including_inline_maps():
    rig = yaml.safe_load(RIG.read_text())
    section = rig["axes"]["camera_arm"]["driver"]
    validate_driver_section(section, "sim.yaml", "axes.camera_arm.driver")
    bad = {**section, "register_map": {"base": "oriental-az", "trigger": 0x66}}
    with pytest.raises(ConfigError, match=r"sim.yaml: axes.camera_arm.driver.register_map.trigger: expected"):
        validate_driver_section(bad, "sim.yaml", "axes.camera_arm.driver")


# ----- exact frames ------------------------------------------------------------------------------
def test_rtu_crc_matches_published_frames():
    assert modbus_crc(bytes.fromhex("01 03 00 00 00 0A")).to_bytes(2, "little") == bytes.fromhex("C5 CD")
    assert modbus_crc(bytes.fromhex("01 83 02")).to_bytes(2, "little") == bytes.fromhex("C0 F1")


def test_tcp_exception_reply_bytes(drive):
    with socket.create_connection(("127.0.0.1", drive.port), timeout=2) as sock:
        # MBAP tid 0x0007, protocol 0, length 6, unit 1 | read holding (03) at 0x1000, 2 registers
        sock.sendall(bytes.fromhex("00 07 00 00 00 06 01 03 10 00 00 02"))
        reply = sock.recv(64)
    # same tid, length 3, unit 1 | function 0x83 (0x03 + error bit), exception 02 illegal data address
    assert reply == bytes.fromhex("00 07 00 00 00 03 01 83 02")


@pytest.mark.parametrize("drive", [("rtu", 40.0)], indirect=True)
def test_rtu_exception_reply_bytes(drive):
    with serial.Serial(drive.endpoint["endpoint"], 115200, timeout=1.0) as port:
        request = bytes.fromhex("01 03 10 00 00 02")
        port.write(request + modbus_crc(request).to_bytes(2, "little"))
        assert port.read(5) == bytes.fromhex("01 83 02 C0 F1")


def test_direct_data_write_is_one_16_register_frame(drive):
    ax = make_axis(drive)
    ax.move_to(120.0).wait()
    frames = [f for f in drive.requests if f[7] == 0x10]
    assert len(frames) == 1
    # MBAP: protocol 0, length 0x27 = unit + 38 PDU bytes, unit 1
    assert frames[0][2:7] == bytes.fromhex("00 00 00 27 01")
    assert frames[0][7:] == bytes.fromhex(
        "10 0058 0010 20"          # write multiple registers at 0x0058, 16 registers, 32 bytes
        "0000 0000  0000 0001"     # operation data No. 0; type 1 = absolute
        "0000 2EE0  0000 0BB8"     # position 12000 steps (120 deg); speed 3000 Hz (30 deg/s)
        "0000 1770  0000 1770"     # rate and stop rate 6000 Hz/s (60 deg/s^2)
        "0000 03E8  0000 0001")    # current 100.0 %; trigger 1 = all data: start
    assert drive.true_position_deg() == pytest.approx(120.0)
    ax.close()


def test_little_word_order_swaps_every_pair():
    dev = SimulatedModbusDrive(SimClock(40.0), word_order="little", position_deg=90.0)
    dev.start()
    try:
        ax = make_axis(dev, word_order="little")
        ax.move_to(10.0).wait()
        frame = [f for f in dev.requests if f[7] == 0x10][0]
        assert frame[13 + 8:13 + 12] == bytes.fromhex("03E8 0000")  # position 1000 steps, low word first
        assert ax.position() == pytest.approx(10.0)
        ax.close()
    finally:
        dev.stop()


# ----- the official client, no goniofrost code -------------------------------------------------
def test_pymodbus_client_moves_the_drive_and_reads_feedback(drive):
    client = ModbusTcpClient("127.0.0.1", port=drive.port, timeout=1, retries=0)
    assert client.connect()
    regs = [0, 0, 0, 1, 0, 5000, 0, 4000, 0, 8000, 0, 8000, 0, 1000, 0, 1]  # 50 deg at 40 deg/s
    assert not client.write_registers(0x0058, regs, device_id=1).isError()

    def status():
        return client.read_holding_registers(0x007E, count=2, device_id=1).registers[1]
    wait_for(lambda: not status() >> 13 & 1)  # MOVE off
    assert status() >> 14 & 1 and status() >> 5 & 1  # IN-POS and READY
    feedback = client.read_holding_registers(0x0120, count=2, device_id=1).registers
    assert client.convert_from_registers(feedback, client.DATATYPE.INT32) == 5000
    client.close()


# ----- the driver against the simulated drive --------------------------------------------------
@pytest.mark.parametrize("drive", [("tcp", 40.0), ("rtu", 40.0)], indirect=True)
def test_driver_moves_reads_and_reports(drive):
    ax = make_axis(drive)
    assert ax.position() == pytest.approx(90.0)
    assert ax.move_to(150.5).wait() == pytest.approx(150.5)
    assert drive.true_position_deg() == pytest.approx(150.5)
    status = ax.status()
    assert (status.moving, status.fault) == (False, None)
    assert status.details["protocol"] == f"modbus-{drive.transport}"
    assert ax.home().wait() == pytest.approx(90.0)
    ax.disable()
    assert drive.free
    ax.enable()
    assert not drive.free
    ax.close()


def test_exception_reply_names_code_and_the_axis_is_stopped(drive):
    ax = make_axis(drive, register_map={"base": "oriental-az", "direct_data": 0x3000})
    with pytest.raises(ExceptionReply) as err:
        ax.move_to(100.0)
    assert err.value.code == 2 and err.value.axis == "camera_arm"
    assert "illegal data address" in str(err.value)
    assert err.value.reply[2:] == bytes.fromhex("00 00 00 03 01 90 02")  # MBAP after the tid | 0x90 02
    assert (0x007C, [0, 1 << 5]) in drive.writes  # STOP on after the refusal
    ax.close()


def test_bad_value_is_refused_with_code_3(drive):
    client = ModbusTcpClient("127.0.0.1", port=drive.port, timeout=1, retries=0)
    client.connect()
    rr = client.write_registers(0x0058, direct_data_registers(1000, 0, 100, 100), device_id=1)
    assert rr.isError() and rr.exception_code == 3  # speed 0
    assert not drive.motion.is_moving()
    client.close()


# ----- injected faults during a move -> typed error, motor stopped ------------------------------
FAULTS = [
    ("tcp", "no_reply", DeviceTimeout, "no reply"),
    ("tcp", "bad_checksum", ProtocolError, "MBAP protocol id"),
    ("tcp", "drop_byte", ProtocolError, "truncated frame"),
    ("tcp", "alarm", DeviceFault, "alarm 0x30: overload"),
    ("tcp", "stall", DeviceFault, "stall"),
    ("tcp", "disconnect", DeviceTimeout, "connection lost"),
    ("rtu", "no_reply", DeviceTimeout, "no reply"),
    ("rtu", "bad_checksum", ChecksumError, "CRC mismatch"),
    ("rtu", "drop_byte", ChecksumError, "CRC mismatch"),
    ("rtu", "alarm", DeviceFault, "alarm 0x30: overload"),
    ("rtu", "stall", DeviceFault, "stall"),
    ("rtu", "disconnect", DeviceTimeout, "connection lost"),
]


@pytest.mark.parametrize("drive, kind, error, text", [((t, 4.0), k, e, x) for t, k, e, x in FAULTS],
                         indirect=["drive"], ids=[f"{t}-{k}" for t, k, _, _ in FAULTS])
def test_fault_during_move_raises_and_stops(drive, kind, error, text):
    ax = make_axis(drive)
    status = ax.move_to(150.0)
    drive.inject_fault(kind)
    with pytest.raises(error, match=text) as err:
        status.wait()
    assert err.value.axis == "camera_arm"
    wait_for(lambda: not drive.motion.is_moving())
    assert drive.true_position_deg() < 149.0  # stopped short of the target
    if kind not in ("alarm", "disconnect"):  # those stop the motor in the drive itself
        assert (0x007C, [0, 1 << 5]) in drive.writes  # the driver commanded STOP
    ax.close()


def test_alarm_reset_recovers(drive):
    ax = make_axis(drive)
    drive.inject_fault("alarm")
    assert ax._read_fault() == "alarm 0x30: overload"
    ax.reset_alarm()
    assert ax._read_fault() == "alarm 0x30: overload"  # the cause is still there
    drive.inject_fault("clear")
    assert ax._read_fault() == "alarm 0x30: overload"  # latched until ALM-RST, as on the drive
    ax.reset_alarm()
    assert ax.status().fault is None
    assert ax.move_to(100.0).wait() == pytest.approx(100.0)
    ax.close()


@pytest.mark.parametrize("drive", [("rtu", 40.0)], indirect=True)
def test_rtu_axis_from_a_validated_rig_section(drive):
    section = {"protocol": "modbus-rtu", "port": drive.endpoint["endpoint"], "baud": 115200,
               "parity": "N", "device_id": 1, "steps_per_deg": 100.0, "word_order": "big",
               "register_map": {"base": "oriental-az", "name": "az-copy"}}
    validate_driver_section(section, "rig.yaml", "axes.camera_arm.driver")
    cfg = AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, home_deg=90.0, tolerance_deg=0.02)
    ax = ModbusAxis.from_section(cfg, section)
    assert ax.link.rtu and ax.map.name == "az-copy"
    ax.connect()
    assert ax.move_to(45.0).wait() == pytest.approx(45.0)
    ax.close()
