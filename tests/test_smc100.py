"""Newport SMC100: exact ASCII bytes, the simulated controller's state machine over a real pty,
the driver against it, and every injected fault -> the documented error and a stopped stage."""
from __future__ import annotations

import time

import pytest
import serial

from drivers.axis import AxisConfig
from drivers.errors import DeviceFault, DeviceTimeout, ExceptionReply, NotConnectedError, ProtocolError
from drivers.smc100 import SMC100Axis
from drivers.smc100_protocol import (
    Cmd, State, build_command, decode_ts, encode_ts, parse_command, parse_reply, te_meaning,
)
from drivers.rig_devices import open_transport
from scripted import ScriptedTransport
from sim.clock import SimClock
from sim.smc100 import SimulatedSMC100

SPEEDUP = 40.0


@pytest.fixture
def device(request):
    speedup = getattr(request, "param", SPEEDUP)  # fault tests run slower so faults hit mid-move
    dev = SimulatedSMC100(SimClock(speedup), address=1, position=3.0, velocity=20.0,
                          acceleration=40.0, limits=(-50.0, 50.0))
    dev.start()
    yield dev
    dev.stop()


@pytest.fixture
def terminal(device):
    """A plain serial terminal (pyserial) on the simulated controller's pty."""
    with serial.Serial(device._port.path, 57600, timeout=1.0) as ser:
        yield ser


# the twin answers from a thread of this process: a pty reply can wait past 0.1 s for a core on a
# busy 2-core host (a partial "1" seen in a suite run), so the twin-backed axes wait longer; the
# tests of injected silence keep 0.1 s (indirect parameter), which must time out before the move ends
TWIN_TIMEOUT_S = 0.5


@pytest.fixture
def axis(device, request):
    cfg = AxisConfig("sample_tilt", (-80.0, 80.0), 20.0, 40.0, home_deg=0.0, tolerance_deg=0.01,
                     retries=1, stall_s=0.3)
    ax = SMC100Axis(cfg, device._port.path, address=1, reply_timeout_s=getattr(request, "param", TWIN_TIMEOUT_S))
    ax.connect(pty_line(device))
    yield ax
    ax.close()


def pty_line(device):
    """The simulated controller's pty, opened by the rig layer as on a real rig (57600 8N1 XON/XOFF)."""
    return open_transport("sample_tilt", {"protocol": "smc100", "port": device._port.path})


def ask(ser: serial.Serial, line: bytes) -> bytes:
    """Send one line, return the reply line (or what arrived before the timeout)."""
    ser.write(line)
    return ser.read_until(b"\r\n")


def wait_for(predicate, timeout_s: float = 3.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < t_end, "condition not reached in time"
        time.sleep(0.005)


# ----- protocol module: bytes from the manual ---------------------------------------------------
def test_command_lines_are_built_as_in_the_manual():
    assert build_command(1, Cmd.MOVE_ABSOLUTE, 10) == b"1PA10\r\n"
    assert build_command(12, Cmd.VELOCITY, 2.5) == b"12VA2.5\r\n"
    assert build_command(1, Cmd.VELOCITY, "?") == b"1VA?\r\n"
    assert build_command(1, Cmd.TELL_STATE) == b"1TS\r\n"
    assert build_command(1, Cmd.MOVE_ABSOLUTE, -0.000001) == b"1PA-0.000001\r\n"
    with pytest.raises(ValueError, match="1-31"):
        build_command(32, Cmd.TELL_STATE)


def test_parse_command_ignores_blanks_and_case():
    cmd = parse_command(b" 1 pa 12.5")
    assert (cmd.address, cmd.letters, cmd.argument) == (1, "PA", "12.5")
    assert parse_command(b"hello") is None


def test_ts_reply_decodes_state_and_error_bits():
    assert parse_reply(b"1TS00000A\r\n", 1, Cmd.TELL_STATE) == "00000A"
    power_up = decode_ts("00000A")
    assert power_up.state == State.NOT_REFERENCED_FROM_RESET and power_up.causes == []
    assert decode_ts("000033").state == State.READY_FROM_MOVING
    faulty = decode_ts("002310")
    assert faulty.state == State.STAGE_ERROR and faulty.is_fault
    assert faulty.causes == ["negative end of run", "positive end of run", "following error"]
    assert encode_ts(0x0020, State.MOVING) == "002028"
    with pytest.raises(ValueError):
        decode_ts("00003")
    with pytest.raises(ValueError):
        parse_reply(b"1TP5\r\n", 1, Cmd.TELL_STATE)


def test_te_letters_are_data():
    assert te_meaning("G") == "displacement out of limits"
    assert te_meaning("H") == "command not allowed in NOT REFERENCED state"
    assert "unknown" in te_meaning("Z")


# ----- a serial terminal against the simulated controller (no goniofrost client code) --------
def test_terminal_power_up_home_move_and_tp(terminal, device):
    assert ask(terminal, b"1TS\r\n") == b"1TS00000A\r\n"
    terminal.write(b"1PA10\r\n")  # PA in NOT REFERENCED: no reply, error H stored
    assert ask(terminal, b"1TE\r\n") == b"1TEH\r\n"
    assert ask(terminal, b"1TE\r\n") == b"1TE@\r\n"  # cleared once read
    terminal.write(b"1OR\r\n")
    assert ask(terminal, b"1TS\r\n") == b"1TS00001E\r\n"  # HOMING
    wait_for(lambda: ask(terminal, b"1TS\r\n") == b"1TS000032\r\n")
    terminal.write(b"1PA12.5\r\n")
    assert ask(terminal, b"1TS?\r\n") == b"1TS000028\r\n"  # MOVING; 'TS?' accepted too
    wait_for(lambda: ask(terminal, b"1TS\r\n") == b"1TS000033\r\n")
    assert ask(terminal, b"1TP\r\n") == b"1TP12.5\r\n"
    assert ask(terminal, b"1VA?\r\n") == b"1VA20\r\n"
    assert device.true_position_deg() == pytest.approx(12.5)


def test_terminal_pa_beyond_sr_gives_te_g(terminal, device):
    terminal.write(b"1OR\r\n")
    wait_for(lambda: ask(terminal, b"1TS\r\n") == b"1TS000032\r\n")
    terminal.write(b"1PA500\r\n")
    assert ask(terminal, b"1TE\r\n") == b"1TEG\r\n"
    assert ask(terminal, b"1TS\r\n") == b"1TS000032\r\n"  # still READY, nothing moved
    terminal.write(b"2PA5\r\n")  # another controller's address: ignored, no error stored
    assert ask(terminal, b"1TE\r\n") == b"1TE@\r\n"
    terminal.write(b"1XX\r\n")
    assert ask(terminal, b"1TE\r\n") == b"1TEA\r\n"


def test_terminal_stop_disable_enable(terminal, device):
    terminal.write(b"1OR\r\n")
    wait_for(lambda: ask(terminal, b"1TS\r\n") == b"1TS000032\r\n")
    terminal.write(b"1PA-40\r\n1ST\r\n")
    wait_for(lambda: ask(terminal, b"1TS\r\n") == b"1TS000033\r\n")
    assert -40.0 < device.true_position_deg() < 0.0
    terminal.write(b"1MM0\r\n")
    assert ask(terminal, b"1TS\r\n") == b"1TS00003C\r\n"
    terminal.write(b"1PA1\r\n")
    assert ask(terminal, b"1TE\r\n") == b"1TEJ\r\n"
    terminal.write(b"1MM1\r\n")
    assert ask(terminal, b"1TS\r\n") == b"1TS000034\r\n"


# ----- the driver against a scripted exchange of exact bytes -----------------------------------
# Lines and replies from the SMC100CC/PP manual as summarised in PROTOCOLS.md section 2: power-up
# state 1TS00000A; OR -> 1E (HOMING) -> 32 (READY from HOMING); PA -> 28 (MOVING) -> 33 (READY from
# MOVING); set commands reply nothing and are checked with TE (1TE@: no error, G: displacement out
# of limits); TS error bit 5 = following error, state 10 = stage error.
CONNECT_SMC = [
    (b"1TS\r\n", b"1TS00000A\r\n"),      # proves a controller answers: NOT REFERENCED after reset
    (b"1SL?\r\n", b"1SL-50\r\n"),         # the controller's own soft limits
    (b"1SR?\r\n", b"1SR50\r\n"),
    (b"1VA20\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),  # velocity 20 units/s, accepted
    (b"1AC40\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),  # acceleration 40 units/s^2, accepted
]
HOME_SMC = [
    (b"1TP\r\n", b"1TP3\r\n"),            # where the stage was at power-up
    (b"1TS\r\n", b"1TS00000A\r\n"), (b"1OR\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
    (b"1TS\r\n", b"1TS00001E\r\n"), (b"1TP\r\n", b"1TP1.5\r\n"),  # HOMING, on the way
    (b"1TS\r\n", b"1TS000032\r\n"), (b"1TP\r\n", b"1TP0\r\n"),    # READY from HOMING, at 0
]


def _scripted_smc(line) -> SMC100Axis:
    cfg = AxisConfig("sample_tilt", (-80.0, 80.0), 20.0, 40.0, home_deg=0.0, tolerance_deg=0.01, retries=0)
    axis = SMC100Axis(cfg, "scripted", address=1, reply_timeout_s=0.5)
    axis.connect(line)
    return axis


def test_driver_connects_homes_and_moves_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + HOME_SMC + [
        (b"1TP\r\n", b"1TP0\r\n"), (b"1PA10\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
        (b"1TS\r\n", b"1TS000028\r\n"), (b"1TP\r\n", b"1TP4.2\r\n"),   # MOVING
        (b"1TS\r\n", b"1TS000033\r\n"), (b"1TP\r\n", b"1TP10\r\n"),    # READY from MOVING
    ])
    axis = _scripted_smc(line)
    assert axis.soft_limits_units == (-50.0, 50.0)
    assert axis.home().wait() == 0.0
    assert axis.move_to(10.0).wait() == 10.0
    axis.close()
    line.finish()


def test_refused_move_reads_te_g_and_stops_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + HOME_SMC + [
        (b"1TP\r\n", b"1TP0\r\n"), (b"1PA60\r\n", b""), (b"1TE\r\n", b"1TEG\r\n"),  # beyond SR
        (b"1ST\r\n", b""),                                                        # the stop
    ])
    axis = _scripted_smc(line)
    axis.home().wait()
    with pytest.raises(ExceptionReply, match="refused: G = displacement out of limits") as err:
        axis.move_to(60.0)
    assert (err.value.code, err.value.command, err.value.reply) == ("G", "1PA60", "1TEG")
    axis.close()
    line.finish()


def test_stage_error_state_is_a_device_fault_and_stops_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + HOME_SMC + [
        (b"1TP\r\n", b"1TP0\r\n"), (b"1PA-30\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
        (b"1TS\r\n", b"1TS002010\r\n"),   # following error (bit 5), state 10: stage error
        (b"1ST\r\n", b""),
    ])
    axis = _scripted_smc(line)
    axis.home().wait()
    with pytest.raises(DeviceFault) as err:
        axis.move_to(-30.0).wait()
    assert err.value.causes == ["following error", "stage error state (TS state 10)"]
    assert err.value.reply == "1TS002010"
    axis.close()
    line.finish()


def test_silence_is_a_timeout_after_the_retry_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + [(b"1TP\r\n", b""), (b"1TP\r\n", b"1TP\r")])  # nothing, then no LF
    cfg = AxisConfig("sample_tilt", (-80.0, 80.0), 20.0, 40.0, retries=1)
    axis = SMC100Axis(cfg, "scripted", address=1, reply_timeout_s=0.3)
    axis.connect(line)
    with pytest.raises(DeviceTimeout, match=r"1TP: no complete reply within 0.3 s \(reply: 31 54 50 0D\)"):
        axis.position()
    axis.close()
    line.finish()


# ----- the driver against the simulated controller ---------------------------------------------
def test_driver_homes_moves_and_reports(axis, device):
    assert axis.status().details["state"] == "NOT_REFERENCED_FROM_RESET"
    assert axis.home().wait() == pytest.approx(0.0)
    assert axis.move_to(-20.0).wait() == pytest.approx(-20.0)
    assert device.true_position_deg() == pytest.approx(-20.0)
    assert axis.position() == pytest.approx(-20.0)
    status = axis.status()
    assert (status.moving, status.fault, status.details["soft_limits_units"]) == (False, None, (-50.0, 50.0))
    assert b"1VA20" in device.received and b"1AC40" in device.received  # profile loaded on connect
    axis.disable()
    assert device.state == State.DISABLE_FROM_READY
    axis.enable()
    assert device.state == State.READY_FROM_DISABLE


def test_driver_converts_units(device):
    cfg = AxisConfig("tilt", (-80.0, 80.0), 10.0, 20.0, home_deg=0.0, tolerance_deg=0.01, retries=0)
    ax = SMC100Axis(cfg, device._port.path, units_per_deg=0.5, reply_timeout_s=TWIN_TIMEOUT_S)
    ax.connect(pty_line(device))
    ax.home().wait()
    assert ax.move_to(30.0).wait() == pytest.approx(30.0)
    assert device.motion.position() == pytest.approx(15.0)  # controller units
    assert b"1VA5" in device.received
    ax.close()


def test_pa_in_not_referenced_is_refused_with_h_and_stopped(axis, device):
    from drivers.errors import NotHomedError
    with pytest.raises(NotHomedError) as err:   # an ExceptionReply the console can name a remedy for
        axis.move_to(10.0)
    assert isinstance(err.value, ExceptionReply)
    assert err.value.code == "H" and err.value.axis == "sample_tilt"
    assert err.value.command == "1PA10" and err.value.reply == "1TEH"
    assert "NOT REFERENCED" in str(err.value)
    wait_for(lambda: list(device.received)[-2:] == [b"1TE", b"1ST"])  # refused, then commanded to stop


def test_pa_beyond_soft_limit_is_refused_with_g(axis, device):
    axis.home().wait()
    with pytest.raises(ExceptionReply) as err:
        axis.move_to(60.0)  # inside the axis limits (+-80) but beyond the controller's SR (50)
    assert err.value.code == "G" and "displacement out of limits" in str(err.value)
    wait_for(lambda: device.received[-1] == b"1ST")
    assert device.true_position_deg() == pytest.approx(0.0)


def test_soft_limits_are_set_on_the_controller(axis, device):
    axis.home().wait()
    axis.set_soft_limits(-10.0, 10.0)
    assert device.limits == [-10.0, 10.0] and b"1SR10" in device.received
    with pytest.raises(ExceptionReply) as err:
        axis.move_to(20.0)
    assert err.value.code == "G"


def test_commands_before_connect_raise(device):
    ax = SMC100Axis(AxisConfig("t", (-1.0, 1.0), 1.0, 1.0), device._port.path)
    with pytest.raises(NotConnectedError):
        ax.position()


# ----- injected faults during a move -> typed error, stage stopped -------------------------------
@pytest.mark.parametrize("device", [4.0], indirect=True)
@pytest.mark.parametrize("axis", [0.1], indirect=True)
@pytest.mark.parametrize("kind, error, text", [
    ("no_reply", DeviceTimeout, "no complete reply"),
    ("bad_checksum", ProtocolError, "expected a reply starting with"),
    ("drop_byte", DeviceTimeout, "no complete reply"),
    ("alarm", DeviceFault, "following error"),
    ("stall", DeviceFault, "stall"),
    ("disconnect", DeviceTimeout, "connection lost"),
])
def test_fault_during_move_raises_and_stops(axis, device, kind, error, text):
    axis.home().wait()
    status = axis.move_to(-45.0)
    device.inject_fault(kind)
    with pytest.raises(error, match=text) as err:
        status.wait()
    assert err.value.axis == "sample_tilt"
    wait_for(lambda: not device.motion.is_moving())
    assert device.true_position_deg() > -45.0 + 1.0  # stopped short of the target
    if kind != "disconnect":  # an unplugged controller cannot hear the stop; it stops by itself
        wait_for(lambda: b"1ST" in list(device.received)[-3:])


def test_alarm_reports_state_10_and_clear_recovers(axis, device):
    axis.home().wait()
    device.inject_fault("alarm")
    with pytest.raises(DeviceFault) as err:
        axis.status()
    assert err.value.causes == ["following error", "stage error state (TS state 10)"]
    assert err.value.reply == "1TS002010"
    with pytest.raises(DeviceFault) as err:  # TS error bits clear once read; the state stays 10
        axis.status()
    assert err.value.causes == ["stage error state (TS state 10)"]
    device.inject_fault("clear")
    assert axis.status().fault is None
    axis.home().wait()
    assert axis.move_to(5.0).wait() == pytest.approx(5.0)


# ----- a lost reply: TE is not asked again (it clears the letter); the move is read back with TH ----------
def test_lost_te_after_pa_is_read_back_with_th_not_repeated_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + HOME_SMC + [
        (b"1TP\r\n", b"1TP0\r\n"), (b"1PA10\r\n", b""), (b"1TE\r\n", b""),  # the TE reply is lost
        (b"1TH\r\n", b"1TH10\r\n"),                                         # set-point 10: PA taken
        (b"1TS\r\n", b"1TS000033\r\n"), (b"1TP\r\n", b"1TP10\r\n"),
    ])
    axis = _scripted_smc(line)
    axis.home().wait()
    assert axis.move_to(10.0).wait() == 10.0
    axis.close()
    line.finish()


def test_lost_te_of_a_refused_pa_is_not_taken_for_an_accepted_one_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + HOME_SMC + [
        (b"1TP\r\n", b"1TP0\r\n"), (b"1PA60\r\n", b""), (b"1TE\r\n", b""),  # refused (G), TE lost
        (b"1TH\r\n", b"1TH0\r\n"),                                          # set-point unchanged
        (b"1ST\r\n", b""),                                                  # retries 0: stop, raise
    ])
    axis = _scripted_smc(line)
    axis.home().wait()
    with pytest.raises(DeviceTimeout, match=r"sample_tilt: 1TE: no complete reply within 0.5 s"):
        axis.move_to(60.0)
    axis.close()
    line.finish()


# ----- identity and the read-only queries of the manual --------------------------------------------
def test_identity_reads_ve_and_id_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + [(b"1VE\r\n", b"1VE SMC100CC 2.0.0\r\n"),
                                            (b"1ID?\r\n", b"1IDURS100CC\r\n"),
                                            (b"1TBG\r\n", b"1TBG DISPLACEMENT OUT OF LIMITS\r\n")])
    axis = _scripted_smc(line)
    assert axis.identity() == {"protocol": "smc100", "address": 1, "version": "SMC100CC 2.0.0",
                               "stage": "URS100CC"}
    assert axis.error_text("G") == "G DISPLACEMENT OUT OF LIMITS"
    axis.close()
    line.finish()


def test_terminal_read_only_queries_answer_in_every_state(terminal, device):
    assert ask(terminal, b"1VE\r\n") == b"1VE SMC100CC 2.0.0\r\n"
    assert ask(terminal, b"1ID?\r\n") == b"1IDURS100CC\r\n"
    assert ask(terminal, b"1PT10\r\n") == b"1PT1\r\n"   # 10 units at VA 20, AC 40: 0.5 + 0.5 s
    assert ask(terminal, b"1TBH\r\n") == b"1TBH COMMAND NOT ALLOWED IN NOT REFERENCED STATE\r\n"
    terminal.write(b"1PA5\r\n")  # refused in NOT REFERENCED: TB alone gives the stored error, once
    assert ask(terminal, b"1TB\r\n") == b"1TBH COMMAND NOT ALLOWED IN NOT REFERENCED STATE\r\n"
    assert ask(terminal, b"1TE\r\n") == b"1TE@\r\n"
    for query, reply in [(b"1SA?", b"1SA1"), (b"1OH?", b"1OH10"), (b"1OT?", b"1OT30"), (b"1FE?", b"1FE0.05"),
                         (b"1BA?", b"1BA0"), (b"1JR?", b"1JR0.05"), (b"1MM?", b"1MM1"), (b"1TH", b"1TH3")]:
        assert ask(terminal, query + b"\r\n") == reply + b"\r\n"
    assert device.state == State.NOT_REFERENCED_FROM_RESET and device.true_position_deg() == 3.0  # nothing moved


def test_lost_te_after_or_is_read_back_with_ts_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + [
        (b"1TP\r\n", b"1TP3\r\n"),
        (b"1TS\r\n", b"1TS00000A\r\n"), (b"1OR\r\n", b""), (b"1TE\r\n", b""),  # the TE reply is lost
        (b"1TS\r\n", b"1TS00001E\r\n"),                                        # HOMING: OR was taken
        (b"1TS\r\n", b"1TS000032\r\n"), (b"1TP\r\n", b"1TP0\r\n"),
    ])
    axis = _scripted_smc(line)
    assert axis.home().wait() == 0.0
    axis.close()
    line.finish()


# ----- a late TE reply: every TE reply looks alike, whichever command it reports on ----------------
def test_a_late_te_reply_does_not_answer_the_te_of_the_next_set_command_on_exact_bytes():
    line = ScriptedTransport(CONNECT_SMC + [
        (b"1SL-40\r\n", b""), (b"1TE\r\n", b""),             # SL's TE reply is late ...
        (b"1SL-40\r\n", b""),                                # ... SL again (a repeatable set command)
        (b"1TP\r\n", b"1TE@\r\n1TP0\r\n"),                   # TP first: the late 1TE@ is skipped
        (b"1TE\r\n", b"1TE@\r\n"),                           # SL accepted
        (b"1SR40\r\n", b""), (b"1TE\r\n", b"1TEC\r\n"),      # SR refused: C, not SL's late '@'
    ])
    cfg = AxisConfig("sample_tilt", (-80.0, 80.0), 20.0, 40.0, retries=1)
    axis = SMC100Axis(cfg, "scripted", address=1, reply_timeout_s=0.5)
    axis.connect(line)
    with pytest.raises(ExceptionReply, match="1SR40") as err:
        axis.set_soft_limits(-40.0, 40.0)
    assert err.value.code == "C"
    axis.close()
    line.finish()


def test_referenced_reads_ts_on_exact_bytes():
    """NOT REFERENCED from reset (0A) before OR, READY from HOMING (32) after it (the manual's TS
    states): the console reads this before it moves any axis."""
    line = ScriptedTransport(CONNECT_SMC + [(b"1TS\r\n", b"1TS00000A\r\n")] + HOME_SMC
                             + [(b"1TS\r\n", b"1TS000032\r\n")])
    axis = _scripted_smc(line)
    assert axis.referenced() is False
    assert axis.home().wait() == 0.0
    assert axis.referenced() is True
    axis.close()
    line.finish()
