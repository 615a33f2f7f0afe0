"""A simulated Dynamixel X-series servo on a pseudo-terminal, byte for byte Protocol 2.0.

PING, READ, WRITE, REBOOT, SYNC_READ and SYNC_WRITE on the X-series control table of PROTOCOLS.md,
operating modes 3 and 4; motion is a trapezoid in encoder counts on the shared SimClock.
"""
from __future__ import annotations

import threading

from drivers.dxl_protocol import (ACCEL_UNIT_RPM2, ADDRESS_SIZE, ALERT_BIT, BROADCAST_ID,
                                  CONTROL_TABLE, EXTENDED_GOAL_LIMIT, ID_INDEX, LENGTH_SIZE,
                                  MODEL_NUMBERS, REV_COUNTS, TABLE_SIZE, VELOCITY_UNIT_RPM,
                                  ErrorCode, FrameError, Instruction, OperatingMode, Reg,
                                  build_status, corrupt_crc, decode_value, drop_error_byte,
                                  find_frame, parse_packet, parse_read_params, parse_write_params)
from sim.clock import SimClock
from sim.faults import ArmedFaults, check_kind
from sim.motion import TrapezoidMotion
from sim.pty_port import PtyServedDevice

ALARM_HW_ERROR = 1 << 5  # "overload": what a blocked servo reports
COUNTS_PER_S_PER_VEL_UNIT = VELOCITY_UNIT_RPM * REV_COUNTS / 60.0  # 15.63 counts/s
COUNTS_PER_S2_PER_ACC_UNIT = ACCEL_UNIT_RPM2 * REV_COUNTS / 3600.0  # 244.1 counts/s^2
NO_LIMIT_SPEED = 1000 * COUNTS_PER_S_PER_VEL_UNIT  # Profile Velocity 0: the motor's top speed
NO_LIMIT_ACCEL = 1e7  # Profile Acceleration 0: a step change of speed
_POLL_S = 0.05  # real seconds between two looks at the stop flag while idle
T = CONTROL_TABLE


class SimulatedDynamixel(ArmedFaults, PtyServedDevice):
    """One X-series servo served on a pty by a background thread.

    Parameters: ``clock`` (shared SimClock), ``id`` (0-252), ``baud`` (reported only: a pty has no
    baud rate), ``model`` (a name of ``MODEL_NUMBERS``), ``counts_per_deg`` (only converts
    ``true_position_deg()``), ``position`` (counts at power-up, in 0..4095 as after power-up).
    Attributes for tests: ``received`` (parsed instruction packets), ``ignored`` (packets seen
    while disconnected), ``faults`` (active injected faults), ``armed`` (faults waiting for the
    next move, see ``sim.faults.ArmedFaults``).
    """

    protocol = "dynamixel"

    def __init__(self, clock: SimClock, id: int = 1, baud: int = 57600, model: str = "XM430-W350",
                 counts_per_deg: float = REV_COUNTS / 360.0, position: int = 0) -> None:
        if model not in MODEL_NUMBERS:
            raise ValueError(f"unknown Dynamixel model {model!r}; expected one of {sorted(MODEL_NUMBERS)}")
        self.clock, self.id, self.baud, self.model = clock, int(id), int(baud), model
        self.counts_per_deg = float(counts_per_deg)
        self.table = bytearray(TABLE_SIZE)
        self.motion = TrapezoidMotion(clock, float(position), NO_LIMIT_SPEED, NO_LIMIT_ACCEL)
        self.faults: set[str] = set()
        self.missing_replies = 0  # miss_reply: this many status packets are lost, then it answers
        self._init_armed()
        self.received: list = []
        self.ignored: list = []
        self._lock = threading.RLock()
        self._init_serving()
        self._power_up()

    def _endpoint_fields(self) -> dict:
        return {"id": self.id, "baud": self.baud}

    def place(self, position: float) -> None:
        """Put the axis at rest at ``position`` (device units), as journaled by an earlier run of the
        session (``sim.rig.SimulatedRig.restore``): nothing moves, no fault strikes."""
        with self._lock:
            self.motion.set_position(float(position))
            self._set(T["goal_position"], round(float(position)))

    def true_position_deg(self) -> float:
        """Ground truth: where the horn really is, in degrees."""
        return self.motion.position() / self.counts_per_deg

    def inject_fault(self, kind: str) -> None:
        """Inject a fault; it persists until ``inject_fault("clear")``.

        miss_reply: the next status packet is lost (the instruction is executed), then it answers
        as before. no_reply: instructions are executed but no status comes back (a broken TX line).
        bad_checksum: status packets carry a wrong CRC. drop_byte: one byte of every status packet
        is lost. alarm: Hardware Error Status = overload, torque off at once (as the servo's
        shutdown does), Alert bit in every status. stall: the horn freezes while Moving stays 1,
        on the move under way and on every later one. disconnect: the cable is pulled; nothing is
        executed or answered. clear: all of it undone (the hardware error too, as a REBOOT would).
        """
        check_kind(kind)
        with self._lock:
            if kind == "miss_reply":  # one lost status, not a lasting fault
                self.missing_replies += 1
                return
            if kind == "clear":
                self.faults.clear()
                self._set(T["hardware_error_status"], 0)
                return
            self.faults.add(kind)
            if kind == "alarm":
                self._set(T["hardware_error_status"], ALARM_HW_ERROR)
                self._torque_off()
            elif kind == "stall":
                self.motion.stall()

    @property
    def torque_on(self) -> bool:
        return bool(self._get(T["torque_enable"]))

    # ----- control table -----------------------------------------------------------------------
    def _power_up(self) -> None:
        """Control table defaults after power-up or REBOOT (the horn stays where it is)."""
        self.table[:] = bytes(TABLE_SIZE)
        self._set(T["model_number"], MODEL_NUMBERS[self.model])
        self._set(T["firmware_version"], 46)
        self._set(T["id"], self.id)
        self._set(T["baud_rate"], 1)
        self._set(T["return_delay_time"], 250)
        self._set(T["operating_mode"], OperatingMode.POSITION)
        self._set(T["moving_threshold"], 10)
        self._set(T["max_position_limit"], REV_COUNTS - 1)
        self._set(T["min_position_limit"], 0)
        self._set(T["status_return_level"], 2)
        self._set(T["present_temperature"], 31)
        self._set(T["goal_position"], round(self.motion.position()))

    def _raw(self, reg: Reg) -> bytes:
        return bytes(self.table[reg.addr:reg.addr + reg.size])

    def _get(self, reg: Reg) -> int:
        return decode_value(self._raw(reg), reg.signed)

    def _set(self, reg: Reg, value: int) -> None:
        self.table[reg.addr:reg.addr + reg.size] = (int(value) & ((1 << 8 * reg.size) - 1)).to_bytes(reg.size, "little")

    def _refresh(self) -> None:
        """Copy the live motion state into the read-only RAM items before a READ."""
        m = self.motion
        pos, vel, moving = m.position(), m.velocity(), m.is_moving()
        self._set(T["present_position"], round(pos))
        self._set(T["present_velocity"], round(vel / COUNTS_PER_S_PER_VEL_UNIT))
        self._set(T["moving"], int(moving))
        in_position = abs(round(pos) - self._get(T["goal_position"])) <= self._get(T["moving_threshold"])
        self._set(T["moving_status"], int(in_position and not moving) | int(moving) << 1)

    # ----- serving -----------------------------------------------------------------------------
    def _serve(self) -> None:
        port, buf = self._port, bytearray()
        try:
            while self._running:
                data = port.read(_POLL_S)
                if not data:
                    continue
                buf += data
                while (frame := find_frame(buf)) is not None:
                    with self._lock:
                        reply = self._handle_frame(frame)
                        if reply and self.missing_replies:
                            self.missing_replies, reply = self.missing_replies - 1, None
                    if reply and not self.faults & {"no_reply", "disconnect"}:
                        port.write(self._corrupt(reply))
        finally:
            port.close()

    def _corrupt(self, reply: bytes) -> bytes:
        """Apply the reply-damaging faults to one status packet."""
        if "bad_checksum" in self.faults:
            reply = corrupt_crc(reply)
        if "drop_byte" in self.faults:
            reply = drop_error_byte(reply)
        return reply

    def _handle_frame(self, frame: bytes) -> bytes | None:
        """Execute one instruction frame; return the status packet to send (None: no reply)."""
        try:
            pkt = parse_packet(frame)
        except FrameError as exc:
            dxl_id = frame[ID_INDEX] if len(frame) > ID_INDEX else None
            if exc.kind == "crc" and dxl_id == self.id:
                return self._status(ErrorCode.CRC)
            return None
        if pkt.dxl_id not in (self.id, BROADCAST_ID):
            return None
        if "disconnect" in self.faults:
            self.ignored.append(pkt)
            return None
        self.received.append(pkt)
        if pkt.instruction in (Instruction.SYNC_READ, Instruction.SYNC_WRITE):
            return self._sync(pkt)
        reply = self._dispatch(pkt)
        if pkt.dxl_id == BROADCAST_ID and pkt.instruction != Instruction.PING:
            return None  # no status to a broadcast READ/WRITE
        return reply

    def _dispatch(self, pkt) -> bytes:
        handlers = {Instruction.PING: self._ping, Instruction.READ: self._read,
                    Instruction.WRITE: self._write, Instruction.REBOOT: self._reboot}
        handler = handlers.get(pkt.instruction)
        if handler is None:
            return self._status(ErrorCode.INSTRUCTION)
        return handler(pkt.params)

    def _status(self, error: int = 0, params: bytes = b"") -> bytes:
        alert = ALERT_BIT if self._get(T["hardware_error_status"]) else 0
        return build_status(self.id, int(error) | alert, params)

    # ----- instructions ------------------------------------------------------------------------
    def _sync(self, pkt) -> bytes | None:
        """SYNC_READ (addr, len, ids: a status from each listed ID in turn; this one servo answers if
        listed) and SYNC_WRITE (addr, len, then [id, data] per servo; never a status)."""
        p, head = pkt.params, ADDRESS_SIZE + LENGTH_SIZE
        if len(p) < head:
            return None
        addr, length = parse_read_params(p)
        if pkt.instruction == Instruction.SYNC_READ:
            return self._read(p[:head]) if self.id in p[head:] else None
        for i in range(head, len(p) - length, length + 1):  # [id, data] per servo
            if p[i] == self.id:
                self._write(p[:ADDRESS_SIZE] + p[i + 1:i + 1 + length])
        return None

    def _ping(self, params: bytes) -> bytes:
        return self._status(0, self._raw(T["model_number"]) + self._raw(T["firmware_version"]))

    def _read(self, params: bytes) -> bytes:
        if len(params) != ADDRESS_SIZE + LENGTH_SIZE:
            return self._status(ErrorCode.DATA_LENGTH)
        addr, length = parse_read_params(params)
        if addr + length > TABLE_SIZE or length == 0:
            return self._status(ErrorCode.DATA_RANGE)
        self._refresh()
        return self._status(0, bytes(self.table[addr:addr + length]))

    def _write(self, params: bytes) -> bytes:
        if len(params) < ADDRESS_SIZE + 1:
            return self._status(ErrorCode.DATA_LENGTH)
        addr, data = parse_write_params(params)
        reg = next((r for r in T.values() if r.addr == addr), None)
        if reg is None or len(data) != reg.size:
            return self._status(ErrorCode.DATA_RANGE if reg is None or len(data) > reg.size
                                else ErrorCode.DATA_LENGTH)
        if not reg.writable or (reg.eeprom and self.torque_on):
            return self._status(ErrorCode.ACCESS)
        return self._status(self._apply_write(reg, decode_value(data, reg.signed)))

    def _apply_write(self, reg: Reg, value: int) -> int:
        """Store a written value and act on it; return the ERR code (0 when accepted)."""
        if reg is T["goal_position"]:
            if not self._goal_allowed(value):
                return ErrorCode.DATA_LIMIT
            self._set(reg, value)
            if self.torque_on:
                start = self.motion.position()
                self.motion.start_move(float(value))
                if abs(value - start) > 0.5:  # goal := present, read to the count, holds: no move
                    self._move_started()
            return 0
        if reg is T["torque_enable"]:
            if value not in (0, 1):
                return ErrorCode.DATA_LIMIT
            if value and self._get(T["hardware_error_status"]):
                return ErrorCode.RESULT_FAIL  # shut down: only a REBOOT re-arms the servo
            self._torque_off() if not value else self._torque_on()
            return 0
        if reg is T["operating_mode"] and value not in tuple(OperatingMode):
            return ErrorCode.DATA_LIMIT
        self._set(reg, value)
        if reg in (T["profile_velocity"], T["profile_acceleration"]):
            self._apply_profile()
        return 0

    def _goal_allowed(self, value: int) -> bool:
        if self._get(T["operating_mode"]) == OperatingMode.EXTENDED_POSITION:
            return abs(value) <= EXTENDED_GOAL_LIMIT
        return self._get(T["min_position_limit"]) <= value <= self._get(T["max_position_limit"])

    def _apply_profile(self) -> None:
        vel, acc = self._get(T["profile_velocity"]), self._get(T["profile_acceleration"])
        self.motion.set_profile(vel * COUNTS_PER_S_PER_VEL_UNIT if vel else NO_LIMIT_SPEED,
                                acc * COUNTS_PER_S2_PER_ACC_UNIT if acc else NO_LIMIT_ACCEL)

    def _torque_on(self) -> None:
        # The servo sets Goal Position to Present Position when torque comes on: it holds still.
        self._set(T["goal_position"], round(self.motion.position()))
        self._set(T["torque_enable"], 1)

    def _torque_off(self) -> None:
        """Torque off: the motor stops driving (the simulated horn stops where it is)."""
        self._set(T["torque_enable"], 0)
        self.motion.set_position(self.motion.position())

    def _reboot(self, params: bytes) -> bytes:
        reply = self._status(0)  # the status goes out before the restart
        self._set(T["hardware_error_status"], 0)
        self.faults.discard("alarm")
        self.motion.set_position(self.motion.position())
        self._power_up()
        return reply
