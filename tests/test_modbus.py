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
from drivers.lamp import Lamp
from drivers.modbus_drive import ModbusAxis, ModbusLink
from drivers.modbus_protocol import modbus_crc
from drivers.modbus_map import ORIENTAL_AZ, direct_data_registers, from_registers, resolve_map, to_registers
from goniofrost.core.errors import ConfigError
from pymodbus.framer.rtu import FramerRTU
from drivers.rig_devices import open_transport
from scripted import ScriptedTransport
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
    ax = ModbusAxis(cfg, rtu=dev.transport == "rtu", timeout_s=0.1, register_map=register_map,
                    word_order=word_order)
    ax.connect(open_link(dev))
    return ax


def open_link(dev: SimulatedModbusDrive):
    """The drive's pty (8N1: ptys refuse parity) or loopback port, opened by the rig layer."""
    if dev.transport == "rtu":
        return open_transport("camera_arm", {"protocol": "modbus-rtu", "port": dev.endpoint["endpoint"],
                                             "parity": "N"})
    return open_transport("camera_arm", {"protocol": "modbus-tcp", "host": "127.0.0.1", "port": dev.port})


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
    ({"base": "oriental-az", "feedback": 1}, "driver.register_map.feedback", "unknown key 'feedback'"),
    ({"feedback_position": 0x120}, "driver.register_map.direct_data", "nothing"),
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


# ----- the driver against a scripted exchange of exact bytes -----------------------------------
# PDUs from the Modbus Application Protocol Specification V1.1b3 (section 6 examples: read holding
# registers 108-110, write multiple registers 2-3, read input register 9, write single coil 173,
# and the exception example of section 7: read coils 1186 -> 81 02); RTU frames from the classic
# Modicon / "Simply Modbus" examples for slave 0x11 with their published CRCs; MBAP headers per the
# Modbus Messaging on TCP/IP Implementation Guide V1.0b; drive registers from the Oriental Motor AZ
# map (PROTOCOLS.md section 3). pymodbus numbers transactions 1, 2, 3... on each new connection.
H = bytes.fromhex
IDLE = "00 00 40 20"     # output status: READY (bit 5) and IN-POS (bit 14)
MOVING = "00 00 20 00"   # output status: MOVE (bit 13)
ALARM = "00 00 00 80"    # output status: ALM-A (bit 7)


def _tcp(tid: int, mbap_len: int, pdu: str) -> bytes:
    """An MBAP frame: transaction id, protocol 0, length (unit + PDU), unit 1, then the PDU."""
    return tid.to_bytes(2, "big") + H("00 00") + mbap_len.to_bytes(2, "big") + H("01") + H(pdu)


def _read_reply(tid: int, words: str) -> bytes:
    """The reply to a read of two holding registers (4 data bytes)."""
    return _tcp(tid, 7, "03 04 " + words)


def _scripted_axis(**kw) -> ModbusAxis:
    cfg = AxisConfig("camera_arm", (-90.0, 90.0), 30.0, 60.0, tolerance_deg=0.02, retries=0)
    return ModbusAxis(cfg, timeout_s=1.0, **kw)


CONNECT_TCP = [(_tcp(1, 6, "03 00 7E 00 02"), _read_reply(1, IDLE))]  # output status at connect
START_MOVE_TCP = [
    (_tcp(2, 6, "03 01 20 00 02"), _read_reply(2, "FF FF FC 18")),  # feedback: -1000 steps = -10 deg
    (_tcp(3, 0x27, "10 0058 0010 20"   # write 16 registers from 0x0058 (32 bytes): direct data
                   "0000 0000 0000 0001"   # operation data No. 0; type 1 = absolute
                   "0000 0BB8 0000 0BB8"   # position 3000 steps (30 deg); speed 3000 Hz (30 deg/s)
                   "0000 1770 0000 1770"   # rate and stop rate 6000 (60 deg/s^2)
                   "0000 03E8 0000 0001"),  # current 100.0 %; trigger 1: start
     _tcp(3, 6, "10 00 58 00 10")),
]
def _stop_tcp(tid: int) -> list:
    """The stop: STOP on (bit 5 of the input command at 0x007C), then every input off."""
    return [(_tcp(tid, 0x0B, "10 00 7C 00 02 04 00 00 00 20"), _tcp(tid, 6, "10 00 7C 00 02")),
            (_tcp(tid + 1, 0x0B, "10 00 7C 00 02 04 00 00 00 00"), _tcp(tid + 1, 6, "10 00 7C 00 02"))]


def test_tcp_link_reads_and_writes_the_spec_example_registers():
    server = ScriptedTransport([
        (H("00 01 00 00 00 06 11 03 00 6B 00 03"), H("00 01 00 00 00 09 11 03 06 02 2B 00 00 00 64")),
        (H("00 02 00 00 00 0B 11 10 00 01 00 02 04 00 0A 01 02"), H("00 02 00 00 00 06 11 10 00 01 00 02")),
    ])
    link = ModbusLink("camera_arm", 0x11, timeout_s=1.0)
    link.open(server)
    assert link.read_holding(0x006B, 3) == [0x022B, 0x0000, 0x0064]
    link.write_holding(0x0001, [0x000A, 0x0102])
    link.close()
    server.finish()


def test_tcp_exception_response_of_the_spec_is_an_exception_reply():
    # the spec's exception example: read coils at 0x04A1 (coil 1186), 1 coil -> 81 02
    server = ScriptedTransport([(H("00 01 00 00 00 06 11 01 04 A1 00 01"), H("00 01 00 00 00 03 11 81 02"))])
    lamp = Lamp(ModbusLink("lamp", 0x11, timeout_s=1.0), coil=0x04A1)
    with pytest.raises(ExceptionReply) as err:
        lamp.connect(server)  # reads the coil to check the lamp answers
    assert err.value.code == 2 and "exception 2: illegal data address" in str(err.value)
    assert err.value.reply == H("00 01 00 00 00 03 11 81 02")
    lamp.link.close()
    server.finish()


def test_tcp_axis_connects_moves_and_arrives_on_exact_bytes():
    server = ScriptedTransport(CONNECT_TCP + START_MOVE_TCP + [
        (_tcp(4, 6, "03 00 7E 00 02"), _read_reply(4, MOVING)),
        (_tcp(5, 6, "03 01 20 00 02"), _read_reply(5, "00 00 05 DC")),  # 1500 steps on the way
        (_tcp(6, 6, "03 00 7E 00 02"), _read_reply(6, IDLE)),
        (_tcp(7, 6, "03 01 20 00 02"), _read_reply(7, "00 00 0B B8")),  # 3000 steps: arrived
    ])
    axis = _scripted_axis()
    axis.connect(server)
    assert axis.move_to(30.0).wait() == pytest.approx(30.0)
    axis.close()
    server.finish()


def test_tcp_alarm_state_is_a_device_fault_and_the_axis_is_stopped():
    server = ScriptedTransport(CONNECT_TCP + START_MOVE_TCP + [
        (_tcp(4, 6, "03 00 7E 00 02"), _read_reply(4, ALARM)),
        (_tcp(5, 6, "03 00 80 00 02"), _read_reply(5, "00 00 00 30")),  # alarm code 0x30: overload
    ] + _stop_tcp(6))
    axis = _scripted_axis()
    axis.connect(server)
    with pytest.raises(DeviceFault, match="alarm 0x30: overload") as err:
        axis.move_to(30.0).wait()
    assert err.value.causes == ["alarm 0x30: overload"]
    axis.close()
    server.finish()


def test_tcp_refused_move_is_an_exception_reply_and_the_axis_is_stopped():
    refused = START_MOVE_TCP[:1] + [(START_MOVE_TCP[1][0], _tcp(3, 3, "90 03"))]  # illegal data value
    server = ScriptedTransport(CONNECT_TCP + refused + _stop_tcp(4))
    axis = _scripted_axis()
    axis.connect(server)
    with pytest.raises(ExceptionReply, match="exception 3: illegal data value") as err:
        axis.move_to(30.0)
    assert err.value.code == 3
    axis.close()
    server.finish()


RTU_SPEC = [  # published frames, CRC low byte first
    (H("11 03 00 6B 00 03 76 87"), H("11 03 06 AE 41 56 52 43 40 49 AD")),
    (H("11 10 00 01 00 02 04 00 0A 01 02 C6 F0"), H("11 10 00 01 00 02 12 98")),
]
RTU_LAMP = [
    (H("11 01 00 AC 00 01 3F 7B"), H("11 01 01 00 55 48")),   # read coil 173: off
    (H("11 05 00 AC FF 00 4E 8B"), H("11 05 00 AC FF 00 4E 8B")),  # write single coil 173 on: echo
    (H("11 04 00 08 00 01 B2 98"), H("11 04 02 00 0A F8 F4")),     # read input register 9: 10 counts
]
RTU_AXIS_ALARM = [
    (H("01 03 00 7E 00 02 A4 13"), H("01 03 04 00 00 40 20 CA 2B")),  # output status: idle
    (H("01 03 00 7E 00 02 A4 13"), H("01 03 04 00 00 00 80 FB 93")),  # ALM-A
    (H("01 03 00 80 00 02 C5 E3"), H("01 03 04 00 00 00 30 FA 27")),  # alarm code 0x30
]


@pytest.mark.parametrize("script", [RTU_SPEC, RTU_LAMP, RTU_AXIS_ALARM], ids=["spec", "lamp", "alarm"])
def test_rtu_frames_of_the_scripts_carry_valid_crcs(script):
    # pymodbus's own CRC (an implementation independent of drivers.modbus_protocol) agrees
    for frame in (f for pair in script for f in pair):
        assert FramerRTU.compute_CRC(frame[:-2]).to_bytes(2, "big") == frame[-2:]
        assert modbus_crc(frame[:-2]).to_bytes(2, "little") == frame[-2:]


def _rtu_link(device_id=0x11) -> ModbusLink:
    return ModbusLink("camera_arm", device_id, rtu=True, timeout_s=1.0)


def test_rtu_link_reads_and_writes_the_published_frames():
    line = ScriptedTransport(RTU_SPEC)
    link = _rtu_link()
    link.open(line)
    assert link.read_holding(0x006B, 3) == [0xAE41, 0x5652, 0x4340]
    link.write_holding(0x0001, [0x000A, 0x0102])
    link.close()
    line.finish()


def test_rtu_lamp_switches_and_reads_the_photodiode_on_published_frames():
    line = ScriptedTransport(RTU_LAMP)
    lamp = Lamp.from_section({"protocol": "modbus-rtu", "port": "scripted", "device_id": 0x11,
                              "baud": 115200, "parity": "N", "coil": 0xAC, "photodiode_register": 0x0008,
                              "full_scale": 10})
    lamp.connect(line)
    lamp.on()
    assert lamp.photodiode() == 1.0
    lamp.close()
    line.finish()


def test_rtu_exception_response_at_connect():
    line = ScriptedTransport([(H("01 03 00 7E 00 02 A4 13"), H("01 83 02 C0 F1"))])
    cfg = AxisConfig("camera_arm", (-90.0, 90.0), 30.0, 60.0, retries=0)
    axis = ModbusAxis(cfg, rtu=True, timeout_s=1.0)
    with pytest.raises(ExceptionReply, match="exception 2: illegal data address") as err:
        axis.connect(line)
    assert err.value.reply == H("01 83 02 C0 F1") and not axis.connected
    line.finish()


def test_rtu_alarm_state_is_a_device_fault():
    line = ScriptedTransport(RTU_AXIS_ALARM)
    cfg = AxisConfig("camera_arm", (-90.0, 90.0), 30.0, 60.0, retries=0)
    axis = ModbusAxis(cfg, rtu=True, timeout_s=1.0)
    axis.connect(line)
    with pytest.raises(DeviceFault, match="alarm 0x30: overload"):
        axis.is_moving()
    axis.close()
    line.finish()


def test_rtu_reply_with_a_bad_crc_is_a_checksum_error():
    bad = H("11 03 06 AE 41 56 52 43 40 49 AE")  # the published reply, last CRC byte damaged
    line = ScriptedTransport([(RTU_SPEC[0][0], bad)])
    link = _rtu_link()
    link.timeout_s = 0.3
    link.open(line)
    with pytest.raises(ChecksumError, match="CRC mismatch") as err:
        link.read_holding(0x006B, 3)
    assert err.value.reply == bad
    link.close()
    line.finish()


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


# Real-time clock (speed-up 1): the 60 degree move takes 2 s of wall time, the margin the fault's
# round trips need before the drive would arrive (at 4x, 0.5 s, a run at load 8 saw it arrive first).
@pytest.mark.parametrize("drive, kind, error, text", [((t, 1.0), k, e, x) for t, k, e, x in FAULTS],
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
    ax.connect(open_transport("camera_arm", section))
    assert ax.move_to(45.0).wait() == pytest.approx(45.0)
    ax.close()


# ----- identity: Read Device Identification (43 / 14), basic objects --------------------------------
def _objects(*texts: bytes) -> str:
    return " ".join(f"{i:02X} {len(t):02X} {t.hex(' ')}" for i, t in enumerate(texts))


def test_identity_is_read_device_identification_on_exact_bytes():
    # the request and reply of the spec's 43/14 example (section 6.21): read code 01 (basic), object
    # 00; conformity 01, no more follows, 3 objects: vendor name, product code, major/minor revision
    objects = _objects(b"Company identification", b"Product code XX", b"V2.11")
    reply = "2B 0E 01 01 00 00 03 " + objects
    server = ScriptedTransport(CONNECT_TCP + [(_tcp(2, 5, "2B 0E 01 00"), _tcp(2, 1 + len(H(reply)), reply))])
    axis = _scripted_axis()
    axis.connect(server)
    assert axis.identity() == {"protocol": "modbus-tcp", "device_id": 1, "register_map": "oriental-az",
                               "vendor": "Company identification", "product_code": "Product code XX",
                               "revision": "V2.11"}
    axis.close()
    server.finish()


def test_a_drive_without_43_14_still_has_an_identity_on_exact_bytes():
    server = ScriptedTransport(CONNECT_TCP + [(_tcp(2, 5, "2B 0E 01 00"), _tcp(2, 3, "AB 01"))])  # illegal function
    axis = _scripted_axis()
    axis.connect(server)
    assert axis.identity()["identification"] == "not supported (exception 1: illegal function)"
    axis.close()
    server.finish()


@pytest.mark.parametrize("drive", [("tcp", 40.0), ("rtu", 40.0)], indirect=True)
def test_the_twin_identifies_itself_to_the_driver_and_the_official_client(drive):
    ax = make_axis(drive)
    assert ax.identity() == {"protocol": f"modbus-{drive.transport}", "device_id": 1, "register_map": "oriental-az",
                             "vendor": "ORIENTAL MOTOR", "product_code": "AZD-KD", "revision": "4.00"}
    ax.close()
    if drive.transport == "tcp":
        client = ModbusTcpClient("127.0.0.1", port=drive.port, timeout=1, retries=0)
        assert client.connect()
        info = client.read_device_information(read_code=0x02, device_id=1).information
        assert info[0x04] == b"AZ series driver (simulated)"  # the regular objects too
        client.close()


def test_rtu_lamp_asks_a_lost_read_again_and_logs_the_retry(caplog):
    read_coil, coil_off = RTU_LAMP[0]
    echo = H("11 08 00 00 00 01 23 5B")  # the resync after an unanswered request (diagnostics echo)
    line = ScriptedTransport([(read_coil, b""), (echo, echo), (read_coil, coil_off)])  # one reply lost, then answered
    lamp = Lamp.from_section({"protocol": "modbus-rtu", "port": "scripted", "device_id": 0x11, "parity": "N",
                              "coil": 0xAC, "photodiode_register": 0x0008})
    with caplog.at_level(logging.INFO, logger="drivers.lamp"):
        lamp.connect(line)  # reads the coil
    assert [r.getMessage() for r in caplog.records] == [
        "lamp: read coil 172: retry 1 of 2 after lamp: read coil 172: no reply within 0.3 s"]
    lamp.close()
    line.finish()


# ----- a late reply to an earlier request (RTU carries no transaction id) ----------------------
# Under load a drive's reply can come after the driver gave up on it and sent the next request.
# An RTU read reply names neither register nor request: "01 03 04 ..." of the output status is
# byte for byte a possible feedback position. After a request that went unanswered the link first
# sends a diagnostics echo (08 / 0000, return query data, a fresh 2-byte token) and skips every
# frame before the echo: the drive answers in order, so once the echo is back nothing earlier is
# still on its way.
RTU_STATUS = H("01 03 00 7E 00 02 A4 13")       # read the output status (0x007E, 2 registers)
RTU_POSITION = H("01 03 01 20 00 02 C4 3D")     # read the feedback position (0x0120, 2 registers)
RTU_IDLE = H("01 03 04 00 00 40 20 CA 2B")
RTU_MOVING = H("01 03 04 00 00 20 00 E3 F3")    # 0x2000 = 8192: as a position, 81.92 deg
RTU_ECHO_1 = H("01 08 00 00 00 01 21 CB")       # echo request = its reply
RTU_ECHO_2 = H("01 08 00 00 00 02 61 CA")
RTU_MOVE = H("01 10 00 58 00 10 20" "0000 0000 0000 0001" "0000 0BB8 0000 0BB8"
             "0000 1770 0000 1770" "0000 03E8 0000 0001" "5A 8A")  # the direct data of START_MOVE_TCP
RTU_MOVE_REPLY = H("01 10 00 58 00 10 40 16")
RTU_LATE = [(RTU_STATUS, RTU_IDLE), (RTU_POSITION, RTU_MOVING), (RTU_ECHO_1, RTU_ECHO_1),
            (RTU_ECHO_2, RTU_ECHO_2), (RTU_MOVE, RTU_MOVE_REPLY), (H("01 88 01 87 C0"), b""),
            (H("01 01 00 00 00 01 FD CA"), H("01 01 01 01 90 48")),
            (H("01 04 02 00 00 01 30 72"), H("01 04 02 C3 50 E9 FC"))]


@pytest.mark.parametrize("script", [RTU_LATE], ids=["late"])
def test_rtu_frames_of_the_late_reply_scripts_carry_valid_crcs(script):
    for frame in (f for pair in script for f in pair if f):
        assert FramerRTU.compute_CRC(frame[:-2]).to_bytes(2, "big") == frame[-2:]


def _rtu_axis(retries: int = 0) -> ModbusAxis:
    cfg = AxisConfig("camera_arm", (-90.0, 90.0), 30.0, 60.0, tolerance_deg=0.02, retries=retries)
    return ModbusAxis(cfg, rtu=True, timeout_s=0.3)


def test_rtu_a_late_status_reply_does_not_answer_the_next_position_read_on_exact_bytes():
    line = ScriptedTransport([
        (RTU_STATUS, RTU_IDLE),                # connect
        (RTU_STATUS, b""),                     # is_moving: the reply is late ...
        (RTU_ECHO_1, RTU_MOVING + RTU_ECHO_1),  # ... and comes after the next request: skipped
        (RTU_POSITION, H("01 03 04 00 00 0B B8 FD 71")),  # 3000 steps
    ])
    axis = _rtu_axis()
    axis.connect(line)
    with pytest.raises(DeviceTimeout):
        axis.is_moving()
    assert axis.position() == pytest.approx(30.0)  # not 81.92: the status word read as a position
    axis.close()
    line.finish()


def test_rtu_a_late_move_reply_does_not_answer_the_read_back_on_exact_bytes():
    line = ScriptedTransport([
        (RTU_STATUS, RTU_IDLE),                                # connect
        (RTU_POSITION, H("01 03 04 FF FF FC 18 BB 1D")),       # -1000 steps = -10 deg
        (RTU_MOVE, b""),                                       # the move's reply is late ...
        (RTU_ECHO_1, RTU_MOVE_REPLY + RTU_ECHO_1),             # ... skipped before the echo
        (RTU_STATUS, RTU_MOVING),                              # read back: moving, the drive took it
    ])
    axis = _rtu_axis()
    axis.connect(line)
    axis.move_to(30.0)  # taken: not sent again, no stop
    axis.close()
    line.finish()


def test_rtu_a_reply_of_another_request_is_a_protocol_error_then_the_link_resyncs_on_exact_bytes():
    # a write's echo where a read's reply should be (not preceded by a timeout this link saw):
    # pymodbus hands the write response to the read; the link must not return its empty registers
    line = ScriptedTransport([
        (RTU_STATUS, RTU_IDLE),                 # connect
        (RTU_POSITION, RTU_MOVE_REPLY),         # not the answer: a ProtocolError, retried ...
        (RTU_ECHO_1, RTU_ECHO_1),               # ... after the echo
        (RTU_POSITION, H("01 03 04 00 00 0B B8 FD 71")),
    ])
    axis = _rtu_axis(retries=1)
    axis.connect(line)
    assert axis.position() == pytest.approx(30.0)
    axis.close()
    line.finish()


def test_rtu_lamp_on_the_axis_link_takes_no_late_status_as_its_photodiode_on_exact_bytes():
    line = ScriptedTransport([
        (RTU_STATUS, RTU_IDLE),                               # the axis connects
        (H("01 01 00 00 00 01 FD CA"), H("01 01 01 01 90 48")),  # the lamp connects: coil 0 on
        (RTU_STATUS, b""),                                    # is_moving: the reply is late
        (RTU_ECHO_1, RTU_MOVING + RTU_ECHO_1),                # ... skipped before the echo
        (H("01 04 02 00 00 01 30 72"), H("01 04 02 C3 50 E9 FC")),  # photodiode 50000 counts
    ])
    axis = _rtu_axis()
    axis.connect(line)
    lamp = Lamp.from_section({"device": "camera_arm"}, {"camera_arm": axis})
    lamp.connect()
    with pytest.raises(DeviceTimeout):
        axis.is_moving()
    assert lamp.photodiode() == 1.0
    axis.close()
    line.finish()


def test_rtu_a_stop_goes_out_even_when_the_resync_gets_no_echo_on_exact_bytes():
    line = ScriptedTransport([
        (RTU_STATUS, RTU_IDLE),                                      # connect
        (RTU_STATUS, b""),                                           # is_moving: no reply
        (RTU_ECHO_1, b""),                                           # the resync: no echo either ...
        (H("01 10 00 7C 00 02 04 00 00 00 20 F5 06"), b""),          # ... STOP still reaches the drive
    ])
    axis = _rtu_axis()
    axis.connect(line)
    with pytest.raises(DeviceTimeout):
        axis.is_moving()
    with pytest.raises(DeviceTimeout, match="resync"):  # no reply can be trusted: the stop is not confirmed
        axis.stop()
    axis.close()
    line.finish()


def test_tcp_a_late_reply_of_an_earlier_transaction_is_skipped_and_the_next_one_taken_on_exact_bytes():
    # the late reply (transaction 2) and the awaited one (3) arrive together: pymodbus skips the
    # first by its transaction id; the second must not be thrown away with it
    server = ScriptedTransport(CONNECT_TCP + [
        (_tcp(2, 6, "03 00 7E 00 02"), b""),                                      # is_moving: late ...
        (_tcp(3, 6, "03 01 20 00 02"), _read_reply(2, MOVING) + _read_reply(3, "00 00 0B B8")),
    ])
    axis = _scripted_axis()
    axis.connect(server)
    with pytest.raises(DeviceTimeout):
        axis.is_moving()
    assert axis.position() == pytest.approx(30.0)  # 3000 steps; never the status word (81.92)
    axis.close()
    server.finish()


@pytest.mark.parametrize("drive", [("rtu", 40.0)], indirect=True)
def test_rtu_a_lost_reply_resyncs_with_the_twin_s_own_diagnostics_echo(drive):
    """The scripted exchanges above play the echo from the manual's bytes; here pymodbus's server
    (the twin) answers it: after a lost reply the link sends 08/0000 and reads the position right."""
    ax = make_axis(drive)
    drive.inject_fault("miss_reply")
    assert ax.position() == pytest.approx(90.0, abs=0.01)  # lost, asked again after the resync
    echoes = [r for r in drive.requests if len(r) > 1 and r[1] == 0x08]
    assert len(echoes) == 1 and echoes[0][2:4] == b"\x00\x00"  # sub-function 0000: return query data
    assert ax.position() == pytest.approx(90.0, abs=0.01)       # in sync again: no second echo
    assert len([r for r in drive.requests if len(r) > 1 and r[1] == 0x08]) == 1
    ax.close()
