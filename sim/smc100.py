"""A simulated Newport SMC100 controller on a pseudo-terminal, byte for byte the ASCII protocol.

The state machine and commands of PROTOCOLS.md section 2: a rejected command replies nothing and
stores an error letter for ``TE``. Motion is a trapezoid on the shared SimClock, in controller
units (degrees for a rotation stage).
"""
from __future__ import annotations

import threading
from collections import deque

from drivers.smc100_protocol import (
    CONTROLLER_MODEL, DEFAULT_BAUD, DISABLE_STATES, FIRMWARE_VERSION, MM_DISABLE, MM_ENABLE,
    NOT_REFERENCED_STATES, READY_STATES, STAGE_ID, CommandLine, ErrorBit, ErrorLetter, State,
    build_reply, encode_ts, format_value, parse_command, te_text,
)
from drivers.axis import trapezoid_time
from sim.clock import SimClock
from sim.faults import ArmedFaults, check_kind
from sim.motion import TrapezoidMotion
from sim.pty_port import PtyPort, PtyServedDevice

ALARM_ERROR_BITS = ErrorBit.FOLLOWING_ERROR  # what a blocked or overloaded stage reports
_POLL_S = 0.02  # real seconds between state updates while idle
# Read-only parameters their "?" query reports (values of a URS100CC's factory configuration).
READ_ONLY_PARAMETERS = {"OH": 10.0, "OT": 30.0, "FE": 0.05, "BA": 0.0, "JR": 0.05}


class SimulatedSMC100(ArmedFaults, PtyServedDevice):
    """One SMC100 controller with one stage, served on a pty by a background thread.

    Parameters: ``clock`` (shared SimClock), ``address`` (1-31), ``baud`` (reported only: a pty
    has no baud rate), ``units_per_deg``, ``position`` (stage position at power-up, units),
    ``velocity`` (VA, units/s), ``acceleration`` (AC, units/s^2), ``limits`` (SL, SR, units).
    """

    protocol = "smc100"

    def __init__(self, clock: SimClock, address: int = 1, baud: int = DEFAULT_BAUD,
                 units_per_deg: float = 1.0, position: float = 0.0, velocity: float = 20.0,
                 acceleration: float = 80.0, limits: tuple[float, float] = (-170.0, 170.0)) -> None:
        self.clock, self.address, self.baud = clock, int(address), int(baud)
        self.units_per_deg = float(units_per_deg)
        self.motion = TrapezoidMotion(clock, float(position), float(velocity), float(acceleration))
        self.velocity, self.acceleration = float(velocity), float(acceleration)
        self.limits = [float(limits[0]), float(limits[1])]
        self._target = float(position)  # the set-point TH reports and PR adds to
        self.state = State.NOT_REFERENCED_FROM_RESET
        self.error_bits = 0
        self.error_letter = ErrorLetter.NONE
        self.faults: set[str] = set()
        self.missing_replies = 0  # miss_reply: this many replies are lost, then it answers again
        self._init_armed()
        self.received: deque[bytes] = deque(maxlen=10_000)  # recent command lines, for tests
        self._lock = threading.RLock()
        self._init_serving()
        self._buffer = b""

    def _endpoint_fields(self) -> dict:
        return {"address": self.address, "baud": self.baud}

    def place(self, position: float) -> None:
        """Put the axis at rest at ``position`` (device units), as journaled by an earlier run of the
        session (``sim.rig.SimulatedRig.restore``): nothing moves, no fault strikes."""
        with self._lock:
            self.motion.set_position(float(position))
            self._target = float(position)

    def true_position_deg(self) -> float:
        """Ground truth: where the stage really is, in degrees."""
        return self.motion.position() / self.units_per_deg

    def inject_fault(self, kind: str) -> None:
        """Inject a fault (see sim.faults.FAULT_KINDS); faults persist until ``inject_fault('clear')``.

        miss_reply: the next reply is lost (a late or garbled line), then it answers as before.
        no_reply: commands are carried out but nothing is sent back (a dead TX line). bad_checksum: ASCII has no checksum, so a reply is
        corrupted instead (its echoed command letters). drop_byte: the LF ending each reply is
        lost. alarm: following-error bit set, state 10 (stage error), motion stopped. stall:
        the stage freezes while the state stays MOVING. disconnect: the controller is unplugged
        (pty closed, motion stopped); only a restart brings it back.
        """
        check_kind(kind)
        with self._lock:
            if kind == "miss_reply":  # one lost reply, not a lasting fault
                self.missing_replies += 1
                return
            if kind == "clear":
                self.faults.clear()
                self.error_bits = 0
                if self.state == State.STAGE_ERROR:
                    self.state = State.NOT_REFERENCED_FROM_RESET
                return
            self.faults.add(kind)
            if kind == "alarm":
                self.error_bits |= ALARM_ERROR_BITS
                self.state = State.STAGE_ERROR
                self.motion.stop()
            elif kind == "stall":
                self.motion.stall()
            elif kind == "disconnect":
                self.motion.stop()

    # --- serving ---------------------------------------------------------------------------
    def _serve(self) -> None:
        port = self._port
        try:
            while self._running and "disconnect" not in self.faults:
                data = port.read(_POLL_S)
                with self._lock:
                    self._update_state()
                    if data:
                        self._feed(port, data)
        finally:
            port.close()

    def _feed(self, port: PtyPort, data: bytes) -> None:
        """Split received bytes into lines (CR, LF or CR LF end a line) and answer each."""
        self._buffer += data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        while b"\n" in self._buffer:
            line, self._buffer = self._buffer.split(b"\n", 1)
            if not line.strip():
                continue
            self.received.append(line)
            reply = self._handle_line(line)
            if reply and self.missing_replies:
                self.missing_replies -= 1
            elif reply and not self.faults & {"no_reply", "disconnect"}:
                port.write(self._faulty(reply))

    def _faulty(self, reply: bytes) -> bytes:
        """Apply the reply-corrupting faults to one reply line."""
        if "bad_checksum" in self.faults:
            reply = reply[:1] + bytes(c ^ 0x01 for c in reply[1:3]) + reply[3:]  # TP -> UQ
        if "drop_byte" in self.faults:
            reply = reply[:-1]
        return reply

    def _update_state(self) -> None:
        """Finish HOMING / MOVING once the trapezoid has ended (a stalled stage never does)."""
        if self.motion.is_moving():
            return
        if self.state == State.HOMING:
            self.state = State.READY_FROM_HOMING
        elif self.state == State.MOVING:
            self.state = State.READY_FROM_MOVING

    # --- commands --------------------------------------------------------------------------
    def _handle_line(self, line: bytes) -> bytes | None:
        if line.strip().upper() == b"ST":  # ST without an address stops every controller
            self.motion.stop()
            return None
        cmd = parse_command(line)
        if cmd is None:
            self.error_letter = ErrorLetter.UNKNOWN_COMMAND
            return None
        if cmd.address != self.address:
            return None  # addressed to another controller on the same line
        handler = getattr(self, f"_cmd_{cmd.letters}", None)
        if handler is None:
            self.error_letter = ErrorLetter.UNKNOWN_COMMAND
            return None
        return handler(cmd)

    def _reject(self, letter: ErrorLetter) -> None:
        self.error_letter = letter
        return None

    def _reply(self, cmd: CommandLine, value: str) -> bytes:
        return build_reply(self.address, cmd.letters, value)

    def _number(self, cmd: CommandLine) -> float | None:
        try:
            return float(cmd.argument)
        except ValueError:
            return None

    def _state_letter(self) -> ErrorLetter:
        """The TE letter for 'not allowed in the current state'."""
        if self.state in NOT_REFERENCED_STATES:
            return ErrorLetter.IN_NOT_REFERENCED
        if self.state in DISABLE_STATES:
            return ErrorLetter.IN_DISABLE
        if self.state == State.HOMING:
            return ErrorLetter.IN_HOMING
        if self.state == State.MOVING:
            return ErrorLetter.IN_MOVING
        if self.state in READY_STATES:
            return ErrorLetter.IN_READY
        return ErrorLetter.NOT_ALLOWED

    def _cmd_TS(self, cmd: CommandLine) -> bytes:
        value = encode_ts(self.error_bits, self.state)
        self.error_bits = 0  # reading TS clears the error bits (the state stays)
        return self._reply(cmd, value)

    def _cmd_TE(self, cmd: CommandLine) -> bytes:
        letter, self.error_letter = self.error_letter, ErrorLetter.NONE
        return self._reply(cmd, letter.value)

    def _cmd_TP(self, cmd: CommandLine) -> bytes:
        return self._reply(cmd, format_value(self.motion.position()))

    def _cmd_TH(self, cmd: CommandLine) -> bytes:
        return self._reply(cmd, format_value(self._target))

    def _cmd_VE(self, cmd: CommandLine) -> bytes:
        return self._reply(cmd, f" {CONTROLLER_MODEL} {FIRMWARE_VERSION}")

    def _cmd_ID(self, cmd: CommandLine) -> bytes | None:
        if not cmd.is_query:  # setting the stage identifier needs CONFIGURATION: not simulated
            return self._reject(self._state_letter())
        return self._reply(cmd, STAGE_ID)

    def _cmd_TB(self, cmd: CommandLine) -> bytes:
        """TB with a letter: its text; TB alone (or TB?): the stored error's text, which it clears."""
        letter = cmd.argument.strip().upper()
        if letter in ("", "?"):
            letter, self.error_letter = self.error_letter.value, ErrorLetter.NONE
        return self._reply(cmd, te_text(letter))

    def _cmd_PT(self, cmd: CommandLine) -> bytes | None:
        """The time (s) a relative move of the argument would take at VA and AC (nothing moves)."""
        step = self._number(cmd)
        if step is None:
            return self._reject(ErrorLetter.PARAMETER)
        return self._reply(cmd, format_value(round(trapezoid_time(step, self.velocity, self.acceleration), 4)))

    def _cmd_SA(self, cmd: CommandLine) -> bytes | None:
        return self._reply(cmd, str(self.address)) if cmd.is_query else self._reject(self._state_letter())

    def _read_only(self, cmd: CommandLine) -> bytes | None:
        if not cmd.is_query:  # setting them needs CONFIGURATION: not simulated
            return self._reject(self._state_letter())
        return self._reply(cmd, format_value(READ_ONLY_PARAMETERS[cmd.letters]))

    _cmd_OH = _cmd_OT = _cmd_FE = _cmd_BA = _cmd_JR = _read_only

    def _cmd_OR(self, cmd: CommandLine) -> None:
        if self.state == State.HOMING:
            return self._reject(ErrorLetter.HOME_STARTED)
        if self.state not in NOT_REFERENCED_STATES:
            return self._reject(self._state_letter())
        self.state = State.HOMING
        self._target = 0.0
        if self.motion.start_move(0.0) > 0:  # the reference (home switch) is the stage's zero
            self._move_started()
        return None

    def _cmd_PA(self, cmd: CommandLine) -> None:
        return self._move(cmd, 0.0)

    def _cmd_PR(self, cmd: CommandLine) -> None:
        return self._move(cmd, self._target)

    def _move(self, cmd: CommandLine, origin: float) -> None:
        step = self._number(cmd)
        if step is None:
            return self._reject(ErrorLetter.PARAMETER)
        if self.state not in READY_STATES:
            return self._reject(self._state_letter())
        target = origin + step
        if not self.limits[0] <= target <= self.limits[1]:
            return self._reject(ErrorLetter.OUT_OF_LIMITS)
        self.state = State.MOVING
        self._target = target
        if self.motion.start_move(target) > 0:
            self._move_started()
        return None

    def _cmd_ST(self, cmd: CommandLine) -> None:
        self.motion.stop()
        if self.state == State.HOMING:  # an interrupted home search leaves the stage unreferenced
            self.state = State.NOT_REFERENCED_FROM_HOMING
        return None

    def _cmd_MM(self, cmd: CommandLine) -> bytes | None:
        if cmd.is_query:
            return self._reply(cmd, "0" if self.state in DISABLE_STATES else "1")
        if cmd.argument == MM_DISABLE and self.state in READY_STATES:
            self.state = State.DISABLE_FROM_READY
        elif cmd.argument == MM_ENABLE and self.state in DISABLE_STATES:
            self.state = State.READY_FROM_DISABLE
        elif cmd.argument in (MM_DISABLE, MM_ENABLE):
            return self._reject(self._state_letter())
        else:
            return self._reject(ErrorLetter.PARAMETER)
        return None

    def _set_or_query(self, cmd: CommandLine, attr: str, index: int | None = None) -> bytes | None:
        """VA / AC / SL / SR: ``?`` queries, a number sets (positive for VA and AC)."""
        current = getattr(self, attr) if index is None else getattr(self, attr)[index]
        if cmd.is_query:
            return self._reply(cmd, format_value(current))
        value = self._number(cmd)
        if value is None or (index is None and value <= 0):
            return self._reject(ErrorLetter.PARAMETER)
        if index is None:
            setattr(self, attr, value)
            self.motion.set_profile(self.velocity, self.acceleration)
        else:
            getattr(self, attr)[index] = value
        return None

    def _cmd_VA(self, cmd: CommandLine) -> bytes | None:
        return self._set_or_query(cmd, "velocity")

    def _cmd_AC(self, cmd: CommandLine) -> bytes | None:
        return self._set_or_query(cmd, "acceleration")

    def _cmd_SL(self, cmd: CommandLine) -> bytes | None:
        return self._set_or_query(cmd, "limits", 0)

    def _cmd_SR(self, cmd: CommandLine) -> bytes | None:
        return self._set_or_query(cmd, "limits", 1)
