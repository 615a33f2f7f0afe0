"""Dynamixel Protocol 2.0: exact bytes from the manual, the driver on a scripted pty exchange, the
driver and dynamixel-sdk against the simulated servo, and every injected fault."""
from __future__ import annotations

import time

import pytest
from conftest import TWIN_REPLY_TIMEOUT_MS
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler
from drivers.rig_devices import open_transport
from scripted import ScriptedTransport
from sdk_retry import sdk_call

from drivers.axis import AxisConfig
from drivers.dxl_protocol import (CONTROL_TABLE as T, ErrorCode, FrameError, Instruction, build_instruction,
                                  build_status, crc16, find_frame, parse_packet, read_params, stuff,
                                  unstuff, write_params)
from drivers.dynamixel import DynamixelAxis
from drivers.errors import (ArrivalError, AxisLimitError, ChecksumError, DeviceFault, DeviceTimeout,
                            ExceptionReply, ProtocolError)
from sim.clock import SimClock
from sim.dynamixel_servo import SimulatedDynamixel

CPD = 4096 / 360.0
H = bytes.fromhex


# ----- exact bytes from the ROBOTIS e-Manual ------------------------------------------------------
def test_crc_check_value():
    assert crc16(b"123456789") == 0xFEE8


def test_ping_to_id_1_exact_bytes():
    assert build_instruction(1, Instruction.PING) == H("FF FF FD 00 01 03 00 01 19 4E")


def test_ping_status_of_an_xm430_w210():
    frame = H("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")  # model 1030, firmware 0x26
    assert build_status(1, 0, H("06 04 26")) == frame
    pkt = parse_packet(frame)
    assert (pkt.dxl_id, pkt.error, int.from_bytes(pkt.params[:2], "little")) == (1, 0, 1030)


def test_read_present_position_and_its_status_exact_bytes():
    assert build_instruction(1, Instruction.READ, read_params(T["present_position"])) == \
        H("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
    status = H("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")  # Present Position 166
    assert build_status(1, 0, (166).to_bytes(4, "little")) == status
    assert int.from_bytes(parse_packet(status).params, "little", signed=True) == 166


def test_write_goal_position_exact_bytes():
    assert build_instruction(1, Instruction.WRITE, write_params(T["goal_position"], 512)) == \
        H("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")


def test_negative_goal_is_twos_complement():
    assert write_params(T["goal_position"], -100) == H("74 00 9C FF FF FF")


def test_byte_stuffing_inserts_fd_and_counts_it_in_len():
    body = H("03 FF FF FD 01")
    assert stuff(body) == H("03 FF FF FD FD 01")
    assert unstuff(stuff(body)) == body
    frame = build_instruction(1, Instruction.WRITE, H("FF FF FD 01"))
    assert frame[5] == 1 + 4 + 1 + 2  # INST + params + the stuffed FD + CRC
    assert parse_packet(frame).params == H("FF FF FD 01")


def test_stuffing_matches_dynamixel_sdk_on_random_packets():
    import random
    rng, ph = random.Random(0), PacketHandler(2.0)
    for _ in range(300):
        params = bytes(rng.choice([0xFF, 0xFD, 0x00, 0x01]) for _ in range(rng.randint(0, 10)))
        pk = [0] * (len(params) + 10)
        pk[4], pk[5], pk[7] = 1, len(params) + 3, 3
        pk[8:8 + len(params)] = params
        pk = ph.addStuffing(pk)  # NB: the SDK's txPacket drops this return value (sends unstuffed)
        total = pk[5] + 7
        pk[0:4] = [0xFF, 0xFF, 0xFD, 0]
        crc = ph.updateCRC(0, pk, total - 2)
        pk[total - 2:total] = [crc & 0xFF, crc >> 8]
        assert bytes(pk[:total]) == build_instruction(1, Instruction.WRITE, params)


def test_error_byte_status_and_bad_crc_are_recognised():
    status = build_status(1, ErrorCode.DATA_LIMIT)
    assert status == H("FF FF FD 00 01 04 00 55 06") + status[-2:]
    assert parse_packet(status).error == 6
    with pytest.raises(FrameError) as info:
        parse_packet(status[:-1] + bytes([status[-1] ^ 1]))
    assert info.value.kind == "crc"


def test_find_frame_skips_garbage_and_waits_for_the_rest():
    ping = build_instruction(1, Instruction.PING)
    buf = bytearray(b"\x00\x12" + ping[:6])
    assert find_frame(buf) is None
    buf += ping[6:] + ping[:3]
    assert find_frame(buf) == ping
    assert bytes(buf) == ping[:3]


# ----- the driver against a scripted exchange of exact bytes ---------------------------------------
def _req(inst, params=b""):
    return build_instruction(1, inst, params)


def _read(name):
    return _req(Instruction.READ, read_params(T[name]))


def _write(name, value):
    return _req(Instruction.WRITE, write_params(T[name], value))


def _ok(params=b"", err=0):
    return build_status(1, err, params)


CONNECT_SCRIPT = [
    (_req(Instruction.PING), _ok(H("FC 03 2E"))),            # model 1020 = XM430-W350
    (_read("operating_mode"), _ok(b"\x03")),                  # position mode after power-up
    (_write("torque_enable", 0), _ok()),                      # EEPROM needs torque off
    (_write("operating_mode", 4), _ok()),                     # extended position mode
    (_write("profile_velocity", 44), _ok()),                  # 60 deg/s / 1.374 deg/s per unit
    (_write("profile_acceleration", 6), _ok()),               # 120 deg/s^2 / 21.46 per unit
]


def _yaw_config(**kw):
    return AxisConfig("sample_yaw", (-180.0, 180.0), 60.0, 120.0, 0.0, 0.1, **kw)


def test_driver_connect_and_signed_position_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SCRIPT + [(_read("present_position"), _ok((-100).to_bytes(4, "little", signed=True)))])
    axis = DynamixelAxis(_yaw_config(), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    assert axis.position() == pytest.approx(-100 / CPD)  # the SDK's read4ByteTxRx would say 4294967196
    axis.close()
    line.finish()


def test_alert_bit_reads_hardware_error_status_and_raises_device_fault():
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_read("moving"), _ok(b"\x00", err=0x80)),                    # Alert bit set
        (_read("hardware_error_status"), _ok(b"\x24", err=0x80)),     # bits 2 and 5
    ])
    axis = DynamixelAxis(_yaw_config(retries=0), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    with pytest.raises(DeviceFault) as info:
        axis.is_moving()
    assert info.value.causes == ["overheating", "overload"]
    assert "sample_yaw" in str(info.value) and "READ moving" in str(info.value)
    axis.close()
    line.finish()


def test_refused_goal_raises_exception_reply_and_commands_a_stop():
    here = (0).to_bytes(4, "little")
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_read("present_position"), _ok(here)),
        (_write("goal_position", 1024), _ok(err=ErrorCode.DATA_LIMIT)),   # refused
        (_read("present_position"), _ok(here)),                           # stop: goal := present
        (_write("goal_position", 0), _ok()),
    ])
    axis = DynamixelAxis(_yaw_config(retries=0), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    with pytest.raises(ExceptionReply) as info:
        axis.move_to(90.0)
    assert info.value.code == 6 and "data limit" in str(info.value)
    axis.close()
    line.finish()


def test_driver_stuffs_a_goal_whose_bytes_hold_a_header():
    # -131073 counts = FF FF FD FF little-endian: the frame must carry FF FF FD FD FF (LEN 10, not 9).
    # dynamixel-sdk 4.1.0's txPacket drops addStuffing's result and would send it unstuffed.
    request = _write("goal_position", -131073)
    assert request == H("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD FF") + request[-2:]
    here = (0).to_bytes(4, "little")
    line = ScriptedTransport(CONNECT_SCRIPT + [(_read("present_position"), _ok(here)), (request, _ok())])
    config = AxisConfig("sample_yaw", (-200000.0, 200000.0), 60.0, 120.0, 0.0, 0.1)
    axis = DynamixelAxis(config, "scripted", 1, 57600, "XM430-W350", 1.0, reply_timeout_ms=200)
    axis.connect(line)
    axis.move_to(-131073.0)
    axis.close()
    line.finish()


def test_a_late_status_of_an_earlier_instruction_does_not_answer_the_next_on_exact_bytes():
    """A read times out; its status comes late, after the retried handshake's PING went out. A
    status names no instruction: taken as the PING's, the 1 data byte would be model number 3 (a
    WRITE's empty status: 0), refused as the wrong model, and not retried. Sizes tell them apart."""
    line = ScriptedTransport([
        (_req(Instruction.PING), _ok(H("FC 03 2E"))),
        (_read("operating_mode"), b""),                                     # its status is late...
        (_req(Instruction.PING), _ok(b"\x03") + _ok(H("FC 03 2E"))),        # ...behind the next PING
        (_read("operating_mode"), _ok() + _ok(b"\x04")),                    # a WRITE's late status
    ] + CONNECT_SCRIPT[4:])
    axis = DynamixelAxis(_yaw_config(), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    assert axis.model_number == 1020
    axis.close()
    line.finish()


def test_a_refusal_is_taken_whatever_its_size_on_exact_bytes():
    line = ScriptedTransport([(_req(Instruction.PING), _ok(err=ErrorCode.DATA_LIMIT))])
    axis = DynamixelAxis(_yaw_config(retries=0), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    with pytest.raises(ExceptionReply, match="data limit"):
        axis.connect(line)
    line.finish()


def test_wrong_model_number_is_refused():
    line = ScriptedTransport([(_req(Instruction.PING), _ok(H("06 04 26")))])  # 1030 = XM430-W210
    axis = DynamixelAxis(_yaw_config(), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    with pytest.raises(ProtocolError, match="model number 1030, expected 1020"):
        axis.connect(line)
    assert not axis.connected
    line.finish()


# ----- against the simulated servo ---------------------------------------------------------------
@pytest.fixture
def servo(request):
    speedup = getattr(request, "param", 40.0)  # fault tests run slower so a move outlasts the detection
    dev = SimulatedDynamixel(SimClock(speedup), id=1, model="XM430-W350", counts_per_deg=CPD)
    entry = dev.start()
    yield dev, entry
    dev.stop()


def pty_line(entry):
    """The simulated servo's pty, opened by the rig layer as on a real rig."""
    return open_transport("sample_yaw", {"protocol": "dynamixel", "port": entry["endpoint"], "baud": 57600})


FAULT_SPEEDUP = 2.0  # the fault tests' servo: they expect reply timeouts, promptly (100 ms)


@pytest.fixture
def axis(servo):
    """The driver on the servo; a loaded host's patience (conftest) unless the test injects faults."""
    dev, entry = servo
    timeout_ms = 100 if dev.clock.speedup == FAULT_SPEEDUP else TWIN_REPLY_TIMEOUT_MS
    ax = DynamixelAxis(_yaw_config(stall_s=0.3), entry["endpoint"], 1, 57600, "XM430-W350", CPD,
                       reply_timeout_ms=timeout_ms)
    ax.connect(pty_line(entry))
    ax.enable()
    yield ax
    dev.inject_fault("clear")
    ax.close()


def test_sdk_pings_moves_and_reads_the_simulated_servo(servo):
    dev, entry = servo
    assert entry == {"protocol": "dynamixel", "endpoint": entry["endpoint"], "id": 1, "baud": 57600}
    port, ph = PortHandler(entry["endpoint"]), PacketHandler(2.0)
    assert port.openPort() and port.setBaudRate(57600)
    try:
        model, result, error = sdk_call(ph.ping, port, 1)
        assert (model, result, error) == (1020, COMM_SUCCESS, 0)
        assert sdk_call(ph.write1ByteTxRx, port, 1, 11, 4) == (COMM_SUCCESS, 0)        # extended mode
        assert sdk_call(ph.write1ByteTxRx, port, 1, 64, 1) == (COMM_SUCCESS, 0)        # torque on
        assert sdk_call(ph.write1ByteTxRx, port, 1, 11, 3) == (COMM_SUCCESS, ErrorCode.ACCESS)  # EEPROM locked
        assert sdk_call(ph.write4ByteTxRx, port, 1, 116, (-500) & 0xFFFFFFFF) == (COMM_SUCCESS, 0)
        deadline = time.monotonic() + 5
        while sdk_call(ph.read1ByteTxRx, port, 1, 122)[0] and time.monotonic() < deadline:
            time.sleep(0.01)
        value, result, _ = sdk_call(ph.read4ByteTxRx, port, 1, 132)
        assert result == COMM_SUCCESS and value == 2**32 - 500  # unsigned from the SDK
        assert dev.true_position_deg() == pytest.approx(-500 / CPD)
    finally:
        port.closePort()


def test_driver_moves_the_simulated_servo(servo, axis):
    dev, _ = servo
    final = axis.move_to(-90.0).wait()
    assert final == pytest.approx(-90.0, abs=0.1)
    assert dev.true_position_deg() == pytest.approx(-90.0, abs=0.1)
    status = axis.status()
    assert (status.moving, status.enabled, status.fault, status.details["model_number"]) == (False, True, None, 1020)


def test_move_beyond_limits_sends_nothing(servo, axis):
    dev, _ = servo
    n = len(dev.received)
    with pytest.raises(AxisLimitError, match=r"sample_yaw.*target 200 deg outside limits \[-180, 180\]"):
        axis.move_to(200.0)
    assert [p.instruction for p in dev.received[n:]] == [Instruction.READ]  # only the start position


def test_move_within_tolerance_sends_nothing(servo, axis):
    dev, _ = servo
    n = len(dev.received)
    status = axis.move_to(0.05)
    assert status.done and status.wait() == 0.0
    assert all(p.instruction == Instruction.READ for p in dev.received[n:])


def _start_then_fault(dev, axis, kind):
    status = axis.move_to(170.0)
    dev.clock.sleep(0.3)
    dev.inject_fault(kind)
    return status


def _seen(count, expected: int) -> int:
    """``count()`` once the twin has read ``expected`` of what it counts, or after 5 s: a stop's
    torque off goes out without waiting for its status, so the twin may still be reading it
    when the driver returns. A frame missing fails; one too many may be read too late to count."""
    deadline = time.monotonic() + 5.0
    while count() < expected and time.monotonic() < deadline:
        time.sleep(0.001)
    return count()


def _assert_stopped(dev):
    deadline = time.monotonic() + 1.0
    while dev.motion.is_moving() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not dev.motion.is_moving()
    assert abs(dev.true_position_deg() - 170.0) > 1.0  # stopped on the way, not arrived


@pytest.mark.parametrize("servo", [FAULT_SPEEDUP], indirect=True)
@pytest.mark.parametrize("kind, error", [("no_reply", DeviceTimeout), ("bad_checksum", ChecksumError),
                                         ("drop_byte", ProtocolError), ("alarm", DeviceFault),
                                         ("stall", DeviceFault)])
def test_injected_fault_raises_and_stops_the_servo(servo, axis, kind, error):
    dev, _ = servo
    status = _start_then_fault(dev, axis, kind)
    with pytest.raises(error) as info:
        status.wait()
    assert info.value.axis == "sample_yaw"
    _assert_stopped(dev)
    if kind == "alarm":
        assert info.value.causes == ["overload"]
    if kind == "stall":
        assert "stall" in str(info.value)
    if kind in ("no_reply", "bad_checksum", "drop_byte"):  # goal := present unreadable -> torque off
        assert not dev.torque_on


@pytest.mark.parametrize("servo", [FAULT_SPEEDUP], indirect=True)
def test_stall_injected_while_idle_stalls_the_next_move(servo, axis):
    dev, _ = servo
    dev.inject_fault("stall")  # nothing moves yet
    status = axis.move_to(90.0)
    with pytest.raises(DeviceFault, match="stall"):
        status.wait()
    assert dev.true_position_deg() == pytest.approx(0.0, abs=0.1)  # the horn never left
    _assert_stopped(dev)


@pytest.mark.parametrize("servo", [FAULT_SPEEDUP], indirect=True)
def test_disconnect_raises_timeout_and_the_stop_was_sent(servo, axis):
    dev, _ = servo
    status = _start_then_fault(dev, axis, "disconnect")
    with pytest.raises(DeviceTimeout):
        status.wait()
    torque_off = (Instruction.WRITE, write_params(T["torque_enable"], 0)[:2])
    assert _seen(lambda: sum((p.instruction, p.params[:2]) == torque_off for p in dev.ignored), 1) >= 1  # sent


@pytest.mark.parametrize("servo", [FAULT_SPEEDUP], indirect=True)
def test_a_stop_after_an_unanswered_stop_is_sent_once_until_the_servo_is_heard_again(servo, axis):
    """A pulled cable: the failed move's own stop is retried (3 attempts), a later stop (the
    engine's, then its exit's) goes out once, as each attempt's frames show; once the servo answers
    again, a stop is retried as before."""
    dev, _ = servo
    status = _start_then_fault(dev, axis, "disconnect")
    with pytest.raises(DeviceTimeout):
        status.wait()
    torque_off = (Instruction.WRITE, write_params(T["torque_enable"], 0)[:2])

    stops = lambda: sum((p.instruction, p.params[:2]) == torque_off for p in dev.ignored)  # noqa: E731
    assert _seen(stops, 3) == 3  # the move's stop: goal := present unreadable, torque off, 3 attempts
    heard = len(dev.ignored)
    with pytest.raises(DeviceTimeout):
        axis.stop()
    assert _seen(stops, 4) == 4  # once
    # one attempt's frames, besides any resync (a READ from address 0): goal := present is tried
    # (the READ of present position goes unanswered), then the torque-off WRITE
    attempt = [(p.instruction, p.params[:2]) for p in dev.ignored[heard:] if p.params[:2] != bytes(2)]
    assert attempt == [(Instruction.READ, T["present_position"].addr.to_bytes(2, "little")), torque_off]
    dev.inject_fault("clear")
    assert -180.0 < axis.position() < 180.0  # heard again (the unplugged servo kept going: a number)
    dev.inject_fault("disconnect")
    with pytest.raises(DeviceTimeout):
        axis.stop()
    assert _seen(stops, 7) == 7  # retried again: 3 attempts


@pytest.mark.parametrize("retries", [0, 2])
def test_one_attempt_on_a_silent_servo_costs_one_reply_timeout(servo, retries):
    """The cable pulled: every attempt waits one reply timeout, however many instructions it
    sends. A read is an attempt per try (retried); a stop is one (goal := present unanswered:
    torque off goes out unwaited), and once unanswered it is sent once; an instruction behind a
    resync that heard nothing is sent unwaited; a home is its position read, its command (never
    repeated) and its stop. Each resync and each instruction used to wait: with retries 0 a stop
    cost 2 or 3 and the home 6."""
    dev, entry = servo
    ax = DynamixelAxis(_yaw_config(retries=retries), entry["endpoint"], 1, 57600, "XM430-W350", CPD,
                       reply_timeout_ms=100)
    ax.connect(pty_line(entry))
    ax.enable()
    dev.inject_fault("disconnect")
    tries = retries + 1
    # (what, attempts): identity's PING and then enable's WRITE each owe a status while others of
    # their size are owed too, so later attempts resync first
    steps = [(ax.position, tries), (ax.is_moving, tries), (ax.stop, tries), (ax.identity, tries),
             (ax.enable, tries), (ax.confirm_stopped, tries), (ax.stop, 1), (ax.status, tries),
             (ax.position, tries), (ax.stop, 1), (ax.home, tries + 2), (ax.stop, 1)]
    counted = []
    for step, _attempts in steps:
        before = ax.reply_timeouts
        with pytest.raises(DeviceTimeout):
            step()
        counted.append(ax.reply_timeouts - before)
    assert counted == [attempts for _, attempts in steps]
    torque_off = (Instruction.WRITE, write_params(T["torque_enable"], 0))
    assert _seen(lambda: sum((p.instruction, p.params) == torque_off for p in dev.ignored), tries + 4) == tries + 4
    ax.close()


@pytest.mark.parametrize("servo", [FAULT_SPEEDUP], indirect=True)
def test_a_damaged_reply_to_a_stop_counts_as_heard(servo, axis):
    """A stop sent once (an earlier one unanswered) that gets a damaged reply: the servo was heard,
    so the next unanswered stop is retried again."""
    dev, _ = servo
    dev.inject_fault("disconnect")
    with pytest.raises(DeviceTimeout):
        axis.stop()  # unanswered: 3 attempts
    dev.inject_fault("clear")
    dev.inject_fault("bad_checksum")
    with pytest.raises(ChecksumError):
        axis.stop()  # sent once, answered with a bad CRC
    dev.inject_fault("clear")
    dev.inject_fault("disconnect")
    before = len(dev.ignored)
    with pytest.raises(DeviceTimeout):
        axis.stop()
    torque_off = (Instruction.WRITE, write_params(T["torque_enable"], 0)[:2])
    assert _seen(lambda: sum((p.instruction, p.params[:2]) == torque_off for p in dev.ignored[before:]), 3) == 3


def test_reboot_after_fault_clears_the_hardware_error(servo):
    dev, entry = servo
    ax = DynamixelAxis(_yaw_config(), entry["endpoint"], 1, 57600, "XM430-W350", CPD,
                       reboot_after_fault=True, reply_timeout_ms=TWIN_REPLY_TIMEOUT_MS)
    ax.connect(pty_line(entry))
    ax.enable()
    dev.inject_fault("alarm")
    with pytest.raises(DeviceFault, match="overload"):
        ax.position()
    assert dev._get(T["hardware_error_status"]) == 0 and dev._get(T["operating_mode"]) == 4
    ax.enable()
    assert ax.move_to(10.0).wait() == pytest.approx(10.0, abs=0.1)
    ax.close()


def test_arrival_outside_tolerance_is_an_arrival_error(servo, axis):
    dev, _ = servo
    status = axis.move_to(45.0)
    dev._set(T["goal_position"], 0)  # someone else re-targets the servo mid-move
    dev.motion.start_move(0.0)
    with pytest.raises(ArrivalError, match="not within 0.1 deg of the target 45 deg"):
        status.wait()


def test_sdk_group_sync_write_and_read(servo):
    from dynamixel_sdk import GroupSyncRead, GroupSyncWrite
    dev, entry = servo
    port, ph = PortHandler(entry["endpoint"]), PacketHandler(2.0)
    assert port.openPort()
    try:
        assert sdk_call(ph.write1ByteTxRx, port, 1, 64, 1) == (COMM_SUCCESS, 0)
        writer = GroupSyncWrite(port, ph, 116, 4)
        assert writer.addParam(1, list((300).to_bytes(4, "little")))
        assert writer.txPacket() == COMM_SUCCESS
        reader = GroupSyncRead(port, ph, 116, 4)
        assert reader.addParam(1)
        for _ in range(5):
            if reader.txRxPacket() == COMM_SUCCESS:
                break
        assert reader.isAvailable(1, 116, 4) and reader.getData(1, 116, 4) == 300
    finally:
        port.closePort()


# ----- a lost status packet: reads are asked again, a goal write is read back, never repeated blind -----
def _move_to_40_on(line: ScriptedTransport) -> None:
    """Move the yaw servo (one retry) to 40 deg over ``line``; every scripted exchange is used."""
    axis = DynamixelAxis(_yaw_config(retries=1), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    assert axis.move_to(40.0).wait() == pytest.approx(40.0, abs=0.1)
    axis.close()
    line.finish()


def test_lost_status_of_a_goal_write_is_read_back_not_repeated_on_exact_bytes():
    goal = round(40.0 * CPD)  # 455 counts
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_read("present_position"), _ok(bytes(4))),
        (_write("goal_position", goal), b""),                       # executed, its status lost
        (_read("goal_position"), _ok(goal.to_bytes(4, "little"))),  # read back: the servo took it
        (_read("moving"), b""), (_read("moving"), _ok(b"\x00")),    # a lost read is asked again
        (_read("present_position"), _ok(goal.to_bytes(4, "little"))),
    ])
    _move_to_40_on(line)


def test_a_goal_the_servo_never_took_is_written_again_once_on_exact_bytes():
    goal = round(40.0 * CPD)
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_read("present_position"), _ok(bytes(4))),
        (_write("goal_position", goal), b""),
        (_read("goal_position"), _ok(bytes(4))),                    # still 0: the write was lost
        (_write("goal_position", goal), _ok()),                     # so it is sent again
        (_read("moving"), _ok(b"\x00")), (_read("present_position"), _ok(goal.to_bytes(4, "little"))),
    ])
    _move_to_40_on(line)


# ----- identity: PING (model number, firmware) and the control table's model number and firmware -----
def test_identity_pings_and_reads_the_model_number_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_req(Instruction.PING), _ok(H("FC 03 2E"))),          # model 1020, firmware 46
        (_read("model_number"), _ok(H("FC 03"))), (_read("firmware_version"), _ok(H("2E"))),
    ])
    axis = DynamixelAxis(_yaw_config(), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    assert axis.identity() == {"protocol": "dynamixel", "id": 1, "model_number": 1020, "model": "XM430-W350",
                               "firmware_version": 46, "model_number_register": 1020, "firmware_register": 46}
    axis.close()
    line.finish()


def test_the_twin_identifies_itself(servo, axis):
    assert axis.identity() == {"protocol": "dynamixel", "id": 1, "model_number": 1020, "model": "XM430-W350",
                               "firmware_version": 46, "model_number_register": 1020, "firmware_register": 46}


# ----- a late status of the same size: another question of the same size after a lost status ------
def test_a_late_status_of_the_same_size_does_not_answer_another_read_on_exact_bytes():
    """READ Moving (1 byte) times out and its retry takes the late status (the same question): the
    retry's own status is now on its way. Taken as the next READ's, Hardware Error Status would
    read 1, a false input-voltage fault. A READ of a size nothing owes (5 bytes from address 0)
    goes first; every status before its own is late and skipped (the servo answers in order)."""
    line = ScriptedTransport(CONNECT_SCRIPT + [
        (_read("present_position"), _ok(bytes(4))),
        (_read("moving"), b""),                                             # late ...
        (_read("moving"), _ok(b"\x01")),                                    # ... taken by the retry
        (_req(Instruction.READ, H("00 00 05 00")),                          # resync: addr 0, 5 bytes
         _ok(b"\x01") + _ok(H("FC 03 00 00 00"))),                          # the retry's late status first
        (_read("hardware_error_status"), _ok(b"\x00")),                     # no fault
        (_read("present_temperature"), _ok(b"\x24")),                       # 36 deg C
    ])
    axis = DynamixelAxis(_yaw_config(retries=1), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    status = axis.status()
    assert status.moving and status.fault is None
    assert status.details["temperature_c"] == 36
    axis.close()
    line.finish()


def test_a_long_silence_does_not_run_out_of_resync_lengths_on_exact_bytes():
    """Torque on and off in turn on a silent servo: each owes a status of size 0 while the other
    does, so each goes behind a resync of a length nothing owes (5 to 63 bytes from address 0).
    Once every length is owed by an unanswered resync, those are long lost: the lengths start
    again at 5 (it raised StopIteration, a crash past every error handler)."""
    torque = [_write("torque_enable", 1), _write("torque_enable", 0)]
    lengths = [*range(5, 64), 5, 6]
    script = [(torque[0], b"")]
    for i, length in enumerate(lengths):
        script += [(_req(Instruction.READ, bytes([0, 0]) + length.to_bytes(2, "little")), b""),
                   (torque[(i + 1) % 2], b"")]   # sent all the same, after the resync heard nothing
    line = ScriptedTransport(CONNECT_SCRIPT + script)
    axis = DynamixelAxis(_yaw_config(retries=0), "scripted", 1, 57600, "XM430-W350", CPD, reply_timeout_ms=200)
    axis.connect(line)
    for i in range(len(lengths) + 1):
        with pytest.raises(DeviceTimeout):
            axis.enable() if i % 2 == 0 else axis.disable()
    assert axis.reply_timeouts == len(lengths) + 1   # one per attempt
    axis.close()
    line.finish()
