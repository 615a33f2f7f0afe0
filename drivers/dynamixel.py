"""Dynamixel X-series servo as an Axis, over Protocol 2.0 (``drivers.dxl_protocol``).

dynamixel-sdk's ``PortHandler`` is the serial transport, adopting the rig layer's connection.
``connect`` checks baud and model, sets extended position mode and the motion profile. The Alert
bit raises ``DeviceFault``, ERR codes ``ExceptionReply``, silence ``DeviceTimeout``, a bad CRC
``ChecksumError``.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Mapping

from dynamixel_sdk import PortHandler

from .axis import Axis, AxisConfig
from .dxl_protocol import (ACCEL_UNIT_RPM2, ALERT_BIT, CONTROL_TABLE, MIN_STATUS, MODEL_NUMBERS,
                           REV_COUNTS, STATUS, VELOCITY_UNIT_RPM, FrameError, Instruction,
                           OperatingMode, Packet, Reg, build_instruction, decode_value,
                           describe_error, find_frame, hardware_error_causes, parse_packet,
                           read_params, write_params)
from .errors import (ChecksumError, DeviceError, DeviceFault, DeviceTimeout, ExceptionReply,
                     ProtocolError)
from .transport import PORT_ERRORS

log = logging.getLogger(__name__)
T = CONTROL_TABLE
DEG_S_PER_VEL_UNIT = VELOCITY_UNIT_RPM * 360.0 / 60.0  # 1.374 deg/s per Profile Velocity unit
DEG_S2_PER_ACC_UNIT = ACCEL_UNIT_RPM2 * 360.0 / 3600.0  # 21.46 deg/s^2 per Profile Acceleration unit
REBOOT_SETTLE_S = 0.5  # the servo is silent for a moment after REBOOT
# The SDK waits only bytes x byte-time + 34 ms for a status; a busy host (or a simulator sharing
# two cores with other work) can miss that. Waiting longer costs nothing when replies do come.
DEFAULT_REPLY_TIMEOUT_MS = 100.0
MODEL_NUMBER = CONTROL_TABLE["model_number"]
PING_REPLY_SIZE = 3  # a PING status carries model number L, H and the firmware version
OWED_KEPT = 16  # statuses still awaited per size, at most
RESYNC_LENGTHS = range(5, 64)  # READ lengths of a resync: no register is longer than 4 bytes


POLL_TIMEOUT_S = 0.001  # the transport's read timeout: the SDK polls; waiting 1 ms frees the CPU


# The SDK's PacketHandler is not used: its txPacket drops addStuffing's result (dynamixel-sdk
# 4.1.0), so a parameter holding FF FF FD would go out unstuffed.
class _Port(PortHandler):
    """dynamixel-sdk's PortHandler on a transport it did not open, with a reply timeout that can be
    made longer than the SDK's bytes x byte-time + 34 ms (USB adapters with a long latency timer,
    a loaded machine).

    ``setupPort`` (the SDK opens ``serial.Serial`` there) adopts ``transport`` instead; the SDK's
    time base is the transport's ``now_ms()`` when it has one (an in-memory transport's clock, so
    that a scripted silence times out without waiting), else the SDK's wall clock.
    """

    def __init__(self, transport, path: str, min_timeout_ms: float) -> None:
        super().__init__(path)
        self._transport = transport
        self.min_timeout_ms = float(min_timeout_ms)

    def setupPort(self, cflag_baud):  # noqa: N802 - SDK name
        transport = self._transport
        transport.timeout = POLL_TIMEOUT_S
        self.ser, self.is_open = transport, True
        transport.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self):  # noqa: N802 - SDK name
        now_ms = getattr(self.ser, "now_ms", None)
        return now_ms() if now_ms is not None else super().getCurrentTime()

    def setPacketTimeout(self, packet_length):  # noqa: N802 - SDK name
        super().setPacketTimeout(packet_length)
        self.packet_timeout = max(self.packet_timeout, self.min_timeout_ms)


class DynamixelAxis(Axis):
    """An X-series servo in extended position mode; angles in degrees, ``counts_per_deg`` counts/deg.

    Driver section keys: ``port`` (opened by the rig layer), ``id``, ``baud``, ``model`` (e.g. "XM430-W350"; checked at
    connect), ``counts_per_deg`` (4096/360 for a direct drive), optional ``reboot_after_fault``
    (bool) and ``reply_timeout_ms`` (minimum reply timeout, default 100 ms).
    """

    def __init__(self, config: AxisConfig, port: str = "", id: int = 1, baud: int = 57600,
                 model: str | None = None, counts_per_deg: float = REV_COUNTS / 360.0,
                 reboot_after_fault: bool = False, reply_timeout_ms: float = DEFAULT_REPLY_TIMEOUT_MS) -> None:
        super().__init__(config)
        self.port_path, self.dxl_id, self.baud, self.model = str(port), int(id), int(baud), model
        self.counts_per_deg = float(counts_per_deg)
        self.reboot_after_fault = bool(reboot_after_fault)
        self.reply_timeout_ms = float(reply_timeout_ms)
        self.model_number: int | None = None
        self.firmware_version: int | None = None
        self._transport = None
        self._port: _Port | None = None
        # status size -> the instructions whose status never came: it may still arrive (``_exchange``)
        self._owed: dict[int, list[bytes]] = {}
        self.reply_timeouts = 0  # status waits that ran out the reply timeout (diagnostics, tests)

    @classmethod
    def from_section(cls, config: AxisConfig, section: Mapping) -> "DynamixelAxis":
        """Build from a validated ``dynamixel`` driver section of the rig file."""
        keys = ("baud", "model", "counts_per_deg", "reboot_after_fault", "reply_timeout_ms")
        return cls(config, port=section["port"], id=section["id"], **{k: section[k] for k in keys if k in section})

    # ----- transport: one instruction frame, one checked status frame --------------------------
    def _transact(self, what: str, instruction: Instruction, params: bytes = b"",
                  check_alert: bool = True, reply_data: int = 0) -> bytes:
        """Send one instruction; return the parameters of its status packet or raise typed errors.

        ``reply_data``: parameter bytes the status will carry (sizes the SDK's reply timeout, and
        tells this instruction's status from a late one of an earlier instruction: ``_exchange``).
        """
        request = build_instruction(self.dxl_id, instruction, params)
        try:
            frame, status = self._exchange(what, request, reply_data)
        except PORT_ERRORS as exc:
            raise DeviceError(self.name, what, None, f"serial port {self.port_path} failed: {exc}") from exc
        code = status.error & ~ALERT_BIT
        if code:
            raise ExceptionReply(self.name, what, frame, describe_error(status.error), code=code)
        if status.error & ALERT_BIT and check_alert:
            self._raise_fault(what, frame)
        return status.params

    def _exchange(self, what: str, request: bytes, reply_data: int) -> tuple[bytes, Packet]:
        """Write ``request``, then read until this servo's status of ``reply_data`` parameter bytes
        arrives or the reply timeout ends.

        Other frames (an adapter's echo, another servo's status) are skipped, and so is a clean status of
        another size: it is the late answer to an earlier instruction that timed out. A status with an
        error code is taken whatever its size. A late status of the same size cannot be told apart, so
        while another instruction of this size owes one, ``_resync`` goes first; after a resync that heard
        nothing the instruction is only posted (``_post``), so an attempt costs one reply timeout.
        """
        if any(owed != request for owed in self._owed.get(reply_data, ())):
            try:
                self._resync(what)
            except DeviceTimeout:
                self._post(request, reply_data)
                raise
            except DeviceError:
                try:
                    self._exchange_once(what, request, reply_data)
                except DeviceError:
                    pass
                raise
        return self._exchange_once(what, request, reply_data)

    def _post(self, request: bytes, reply_data: int) -> None:
        """Write ``request`` without waiting for its status, which it then owes (a late one is
        skipped by its size or resynced past, ``_exchange``)."""
        self._port.clearPort()
        self._port.writePort(request)
        self._owe(request, reply_data)

    def _owe(self, request: bytes, reply_data: int) -> None:
        owed = self._owed.setdefault(reply_data, [])
        owed.append(request)
        del owed[:-OWED_KEPT]  # a long silence: the oldest are long lost, not late

    def _resync(self, what: str) -> None:
        """READ from address 0 a length no instruction owes a status of (5 bytes and up): the first
        clean status of that size is this READ's, and the servo answers in order, so every late
        status came before it (skipped by size) and nothing is owed any more."""
        free = [n for n in RESYNC_LENGTHS if not self._owed.get(n)]
        if not free:  # every length owed by an unanswered resync: a long silence, those are long lost, not late
            for n in RESYNC_LENGTHS:
                self._owed.pop(n, None)
            free = list(RESYNC_LENGTHS)
        length = free[0]
        request = build_instruction(self.dxl_id, Instruction.READ,
                                    bytes([0, 0]) + length.to_bytes(2, "little"))
        self._exchange_once(f"{what}: resync (READ addr 0, {length} bytes)", request, length, strict=True)
        self._owed.clear()

    def _exchange_once(self, what: str, request: bytes, reply_data: int,
                       strict: bool = False) -> tuple[bytes, Packet]:
        """One instruction and its status (``_exchange``); ``strict``: a status of another size
        is never taken, not even a refusal. Keeps ``_owed``: an instruction without a clean
        status of its own owes one; a late status skipped by its size pays one of that size."""
        try:
            return self._read_status(what, request, reply_data, strict)
        except (DeviceTimeout, ProtocolError, ChecksumError):
            self._owe(request, reply_data)
            raise

    def _read_status(self, what: str, request: bytes, reply_data: int, strict: bool) -> tuple[bytes, Packet]:
        reply_size = MIN_STATUS + reply_data
        port = self._port
        port.clearPort()  # a late status must not answer this instruction
        port.writePort(request)
        port.setPacketTimeout(reply_size)
        buf = bytearray()
        while True:
            buf += port.readPort(reply_size)
            frame = find_frame(buf)
            if frame is not None:
                status = self._parse_status(what, frame)
                if status.instruction == STATUS and status.dxl_id == self.dxl_id:
                    if len(status.params) == reply_data or (status.error & ~ALERT_BIT and not strict):
                        return frame, status
                    if self._owed.get(len(status.params)):  # the late status of one of them
                        self._owed[len(status.params)].pop(0)
            elif port.isPacketTimeout():
                self.reply_timeouts += 1
                if buf:
                    raise ProtocolError(self.name, what, bytes(buf), "incomplete status packet")
                raise DeviceTimeout(self.name, what, None, "no status packet within the reply timeout")

    def _parse_status(self, what: str, frame: bytes) -> Packet:
        try:
            return parse_packet(frame)
        except FrameError as exc:
            error = ChecksumError if exc.kind == "crc" else ProtocolError
            raise error(self.name, what, frame, f"status {exc}") from exc

    def _raise_fault(self, what: str, rx: bytes) -> None:
        status = self._read(T["hardware_error_status"], check_alert=False)
        causes = hardware_error_causes(status) or ["alert bit set, hardware error status 0"]
        fault = DeviceFault(self.name, what, rx, causes)
        if self.reboot_after_fault:
            try:
                self.reboot()
            except DeviceError as exc:
                log.warning("%s: reboot after fault failed: %s", self.name, exc)
        raise fault

    def _read(self, reg: Reg, check_alert: bool = True) -> int:
        data = self._transact(f"READ {self._name_of(reg)} (addr {reg.addr}, {reg.size} bytes)",
                              Instruction.READ, read_params(reg), check_alert, reply_data=reg.size)
        if len(data) != reg.size:
            raise ProtocolError(self.name, f"READ addr {reg.addr}", data,
                                f"expected {reg.size} data bytes, got {len(data)}")
        return decode_value(data, reg.signed)  # the SDK's read4ByteTxRx would be unsigned

    def _write(self, reg: Reg, value: int, check_alert: bool = True) -> None:
        self._transact(f"WRITE {self._name_of(reg)} (addr {reg.addr}) = {value}",
                       Instruction.WRITE, write_params(reg, value), check_alert)

    def _post_write(self, reg: Reg, value: int) -> None:
        """WRITE ``value`` to ``reg`` without waiting for its status (``_post``)."""
        try:
            self._post(build_instruction(self.dxl_id, Instruction.WRITE, write_params(reg, value)), 0)
        except PORT_ERRORS as exc:
            raise DeviceError(self.name, f"WRITE {self._name_of(reg)}", None,
                              f"serial port {self.port_path} failed: {exc}") from exc

    @staticmethod
    def _name_of(reg: Reg) -> str:
        return next(name for name, r in T.items() if r is reg)

    # ----- public extras ------------------------------------------------------------------------
    def reboot(self) -> None:
        """REBOOT the servo (clears a hardware error; torque comes back off), then restore the mode
        and profile. The axis must be enabled again before moving."""
        self._transact("REBOOT", Instruction.REBOOT, check_alert=False)
        time.sleep(REBOOT_SETTLE_S)
        self._enabled = False
        self._ensure_extended_mode()
        self._apply_motion_profile(self.config.speed_deg_s, self.config.accel_deg_s2)

    # ----- Axis hooks ---------------------------------------------------------------------------
    def _attach(self, transport) -> None:
        self._transport = transport
        port = _Port(transport, self.port_path, self.reply_timeout_ms)
        if not port.setBaudRate(self.baud):  # the SDK's baud table; setupPort adopts the transport
            raise DeviceError(self.name, f"set baud {self.baud}", None, "baud rate not supported by the SDK")
        self._port = port

    def _connect(self) -> None:
        self._check_model()
        self._ensure_extended_mode()

    def _read_identity(self) -> dict:
        """PING (model number, firmware version), then the control table's own copies (read-only)."""
        self._check_model()
        return {"protocol": "dynamixel", "id": self.dxl_id, "model_number": self.model_number,
                "model": next((m for m, n in MODEL_NUMBERS.items() if n == self.model_number), None),
                "firmware_version": self.firmware_version,
                "model_number_register": self._read(T["model_number"], check_alert=False),
                "firmware_register": self._read(T["firmware_version"], check_alert=False)}

    def _move_taken(self, target: float) -> bool:
        """Goal Position (116) holds the target once the servo took the write."""
        return self._read(T["goal_position"], check_alert=False) == round(target * self.counts_per_deg)

    def _check_model(self) -> None:
        data = self._transact("PING", Instruction.PING, check_alert=False, reply_data=PING_REPLY_SIZE)
        self.model_number = decode_value(data[:MODEL_NUMBER.size], False)
        self.firmware_version = data[MODEL_NUMBER.size] if len(data) > MODEL_NUMBER.size else None
        expected = MODEL_NUMBERS.get(self.model) if self.model else None
        ok = self.model_number == expected if expected else self.model_number in MODEL_NUMBERS.values()
        if not ok:
            exc = ProtocolError(self.name, "PING", data,
                                f"model number {self.model_number}, expected "
                                f"{expected if expected else 'an X-series model'} ({self.model or 'X series'})")
            exc.transient = False  # asking again will not change the model
            raise exc

    def _ensure_extended_mode(self) -> None:
        if self._read(T["operating_mode"], check_alert=False) != OperatingMode.EXTENDED_POSITION:
            self._write(T["torque_enable"], 0)  # EEPROM items are writable only with torque off
            self._write(T["operating_mode"], OperatingMode.EXTENDED_POSITION)

    def _close(self) -> None:
        self._port = None
        if self._transport is not None:
            transport, self._transport = self._transport, None
            transport.close()

    def _command_move(self, deg: float) -> None:
        self._write(T["goal_position"], round(deg * self.counts_per_deg))

    def _read_position(self) -> float:
        return self._read(T["present_position"]) / self.counts_per_deg

    def _read_moving(self) -> bool:
        return bool(self._read(T["moving"]))

    def _read_at_rest(self) -> tuple[bool, float]:
        """Moving = 0, read past the Alert bit: a servo shut down by a hardware error has no torque."""
        moving = self._read(T["moving"], check_alert=False)
        return not moving, self._read(T["present_position"], check_alert=False) / self.counts_per_deg

    def _command_stop(self) -> None:
        """Hold where the horn is (Goal := Present); if that cannot be read, torque off.

        No Alert check here: a servo in a hardware-error state must still be told to stop. When
        nothing was heard (a reply timeout), torque off is posted, not waited for: the servo may
        hear without being heard, and the attempt has already cost its one reply timeout.
        """
        try:
            here = self._read(T["present_position"], check_alert=False)
            self._write(T["goal_position"], here, check_alert=False)
        except DeviceTimeout as exc:
            log.warning("%s: stop by goal := present unanswered (%s); torque off sent unanswered", self.name, exc)
            self._enabled = False
            self._post_write(T["torque_enable"], 0)
            raise
        except DeviceError as exc:
            log.warning("%s: stop by goal := present failed (%s); switching torque off", self.name, exc)
            self._enabled = False
            self._write(T["torque_enable"], 0, check_alert=False)

    def _set_enabled(self, enabled: bool) -> None:
        self._write(T["torque_enable"], int(enabled))

    def _read_fault(self) -> str | None:
        causes = hardware_error_causes(self._read(T["hardware_error_status"], check_alert=False))
        return ", ".join(causes) or None

    def _apply_motion_profile(self, speed_deg_s: float, accel_deg_s2: float) -> None:
        self._write(T["profile_velocity"], max(1, round(speed_deg_s / DEG_S_PER_VEL_UNIT)))
        self._write(T["profile_acceleration"], max(1, round(accel_deg_s2 / DEG_S2_PER_ACC_UNIT)))

    def _status_details(self) -> dict:
        return {"model_number": self.model_number, "id": self.dxl_id, "port": self.port_path,
                "temperature_c": self._read(T["present_temperature"], check_alert=False)}
