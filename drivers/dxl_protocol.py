"""Dynamixel Protocol 2.0 in one place: frames, CRC-16, byte stuffing, control table, error codes.

Shared by the driver and the simulated servo. Facts from PROTOCOLS.md section 1. Frame
(multi-byte fields little-endian)::

    FF FF FD | 00       | ID | LEN_L LEN_H | INST (0x55 in a status) | [ERR] params | CRC_L CRC_H
    header   | reserved |    | bytes after LEN, stuffed, CRC included | stuffed body | CRC-16/BUYPASS
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd"
RESERVED = 0x00
# byte groups of a frame (before unstuffing)
ID_INDEX = 4
LEN_FIELD = slice(5, 7)      # little-endian count of the bytes after it
PREFIX_SIZE = 7              # header, reserved, ID, LEN: what LEN does not count
INSTRUCTION_INDEX = 7        # 0x55 in a status packet
ERROR_INDEX = 8              # the ERR byte of a status packet
CRC_SIZE = 2
MIN_FRAME = PREFIX_SIZE + 1 + CRC_SIZE  # an instruction without parameters
MIN_STATUS = MIN_FRAME + 1              # a status: instruction 0x55 and the ERR byte
STATUS = 0x55  # the instruction byte of every status packet
BROADCAST_ID = 0xFE
MAX_ID = 0xFC  # the SDK accepts status packets only from IDs <= 0xFC

REV_COUNTS = 4096  # encoder counts per revolution
VELOCITY_UNIT_RPM = 0.229  # Profile Velocity / Present Velocity: rpm per unit
ACCEL_UNIT_RPM2 = 214.577  # Profile Acceleration: rev/min^2 per unit (third-party figure)
EXTENDED_GOAL_LIMIT = 1_048_575  # |goal| in extended position mode (+-256 turns)


class Instruction(enum.IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    BULK_READ = 0x92
    BULK_WRITE = 0x93


class OperatingMode(enum.IntEnum):
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5


@dataclass(frozen=True)
class Reg:
    """One control-table item: address, size in bytes, signedness, writable, EEPROM (address < 64)."""

    addr: int
    size: int
    signed: bool = False
    writable: bool = True

    @property
    def eeprom(self) -> bool:
        return self.addr < 64


CONTROL_TABLE: dict[str, Reg] = {  # X series (XM430 / XM540 share these addresses)
    "model_number": Reg(0, 2, writable=False),
    "firmware_version": Reg(6, 1, writable=False),
    "id": Reg(7, 1),
    "baud_rate": Reg(8, 1),
    "return_delay_time": Reg(9, 1),
    "operating_mode": Reg(11, 1),
    "homing_offset": Reg(20, 4, signed=True),
    "moving_threshold": Reg(24, 4),
    "max_position_limit": Reg(48, 4),
    "min_position_limit": Reg(52, 4),
    "torque_enable": Reg(64, 1),
    "led": Reg(65, 1),
    "status_return_level": Reg(68, 1),
    "hardware_error_status": Reg(70, 1, writable=False),
    "profile_acceleration": Reg(108, 4),
    "profile_velocity": Reg(112, 4),
    "goal_position": Reg(116, 4, signed=True),
    "moving": Reg(122, 1, writable=False),
    "moving_status": Reg(123, 1, writable=False),
    "present_velocity": Reg(128, 4, signed=True, writable=False),
    "present_position": Reg(132, 4, signed=True, writable=False),
    "present_temperature": Reg(146, 1, writable=False),
}
TABLE_SIZE = 147  # bytes 0..146 (the last item is Present Temperature)

MODEL_NUMBERS = {"XM430-W350": 1020, "XM430-W210": 1030, "XM540-W270": 1120, "XM540-W150": 1130}

BAUD_CODES = {9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5,
              4_000_000: 6, 4_500_000: 7}


class ErrorCode(enum.IntEnum):
    """Bits 0-6 of the status ERR byte (a number, not a bit mask); bit 7 is the Alert flag."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


ALERT_BIT = 0x80
ERROR_TEXT = {
    ErrorCode.RESULT_FAIL: "result fail (instruction could not be processed)",
    ErrorCode.INSTRUCTION: "instruction error (undefined instruction, or ACTION without REG_WRITE)",
    ErrorCode.CRC: "CRC error (the servo saw a corrupted instruction)",
    ErrorCode.DATA_RANGE: "data range error (data too long for the address)",
    ErrorCode.DATA_LENGTH: "data length error (data too short for the address)",
    ErrorCode.DATA_LIMIT: "data limit error (value outside the allowed range)",
    ErrorCode.ACCESS: "access error (read-only address, or EEPROM write with torque on)",
}

HW_ERROR_BITS = {  # Hardware Error Status (address 70)
    0: "input voltage error",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock (circuit short)",
    5: "overload",
}


def describe_error(err: int) -> str:
    """Readable meaning of a status ERR byte (without the Alert bit)."""
    code = err & ~ALERT_BIT
    try:
        return ERROR_TEXT[ErrorCode(code)]
    except (ValueError, KeyError):
        return f"unknown error {code}"


def hardware_error_causes(status: int) -> list[str]:
    """Readable causes set in a Hardware Error Status value (address 70)."""
    return [text for bit, text in HW_ERROR_BITS.items() if status >> bit & 1] or (
        [f"unknown hardware error bits 0x{status:02X}"] if status else [])


# ----- CRC-16/BUYPASS (polynomial 0x8005, init 0, no reflection, no final XOR) ------------------
def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16 of Protocol 2.0 over ``data`` (header to the last parameter, stuffed)."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


# ----- byte stuffing ---------------------------------------------------------------------------
def stuff(body: bytes) -> bytes:
    """Insert an extra FD after every FF FF FD in ``body`` (instruction to last parameter).

    The two bytes before ``body`` in a frame are LEN_L LEN_H, never FF FF, so scanning the body
    alone finds every occurrence (as the SDK does).
    """
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and out[-3:] == HEADER:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the FD stuffed after every FF FF FD in ``body``."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if out[-3:] == HEADER and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1  # skip the stuffed FD
        i += 1
    return bytes(out)


# ----- frames ---------------------------------------------------------------------------------
def build_packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete instruction (or, with instruction 0x55 and ERR first in params, status) frame."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + CRC_SIZE
    frame = HEADER + bytes([RESERVED, dxl_id]) + length.to_bytes(2, "little") + body
    return frame + crc16(frame).to_bytes(CRC_SIZE, "little")


def build_instruction(dxl_id: int, instruction: Instruction, params: bytes = b"") -> bytes:
    """An instruction packet, e.g. ``build_instruction(1, Instruction.PING)``."""
    return build_packet(dxl_id, int(instruction), params)


def build_status(dxl_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """A status packet: instruction 0x55, the ERR byte, then the parameters."""
    return build_packet(dxl_id, STATUS, bytes([error]) + bytes(params))


ADDRESS_SIZE = 2  # every READ/WRITE/SYNC starts with the control-table address, little-endian
LENGTH_SIZE = 2   # READ and SYNC_* follow it with a data length


def read_params(reg: Reg) -> bytes:
    """Parameters of a READ of one control-table item: address and length, little-endian."""
    return reg.addr.to_bytes(ADDRESS_SIZE, "little") + reg.size.to_bytes(LENGTH_SIZE, "little")


def write_params(reg: Reg, value: int) -> bytes:
    """Parameters of a WRITE of one item: address then the value in ``reg.size`` bytes (two's complement)."""
    return reg.addr.to_bytes(ADDRESS_SIZE, "little") + (value & ((1 << 8 * reg.size) - 1)).to_bytes(reg.size, "little")


def parse_read_params(params: bytes) -> tuple[int, int]:
    """Address and length of READ parameters (also the first 4 bytes of SYNC_READ / SYNC_WRITE)."""
    return (int.from_bytes(params[:ADDRESS_SIZE], "little"),
            int.from_bytes(params[ADDRESS_SIZE:ADDRESS_SIZE + LENGTH_SIZE], "little"))


def parse_write_params(params: bytes) -> tuple[int, bytes]:
    """Address and data bytes of WRITE parameters."""
    return int.from_bytes(params[:ADDRESS_SIZE], "little"), bytes(params[ADDRESS_SIZE:])


def decode_value(data: bytes, signed: bool) -> int:
    """Little-endian integer of a control-table item."""
    return int.from_bytes(bytes(data), "little", signed=signed)


class FrameError(ValueError):
    """A received frame that cannot be used: ``kind`` is "header", "incomplete" or "crc"."""

    def __init__(self, kind: str, frame: bytes, text: str) -> None:
        self.kind, self.frame = kind, bytes(frame)
        super().__init__(text)


@dataclass(frozen=True)
class Packet:
    """A parsed frame: for a status packet ``instruction`` is 0x55 and ``error`` the ERR byte."""

    dxl_id: int
    instruction: int
    params: bytes
    error: int | None = None


def frame_length(buf: bytes) -> int | None:
    """Total length of the frame starting at ``buf[0]`` once its LEN field has arrived, else None."""
    if len(buf) < PREFIX_SIZE:
        return None
    return PREFIX_SIZE + int.from_bytes(buf[LEN_FIELD], "little")


def parse_packet(frame: bytes) -> Packet:
    """Check and decode one complete frame (header, length, CRC), unstuffing its body."""
    frame = bytes(frame)
    start = HEADER + bytes([RESERVED])
    if frame[:len(start)] != start:
        raise FrameError("header", frame, f"bad header {frame[:len(start)].hex(' ')}")
    total = frame_length(frame)
    if total is None or len(frame) < total or total < MIN_FRAME:
        raise FrameError("incomplete", frame, f"incomplete frame: {len(frame)} bytes, LEN says {total}")
    frame = frame[:total]
    crc = int.from_bytes(frame[-CRC_SIZE:], "little")
    if crc16(frame[:-CRC_SIZE]) != crc:
        raise FrameError("crc", frame, f"CRC {crc:04X}, computed {crc16(frame[:-CRC_SIZE]):04X}")
    body = unstuff(frame[PREFIX_SIZE:-CRC_SIZE])  # instruction, [ERR,] parameters
    if body[0] == STATUS:
        if len(body) < 2:
            raise FrameError("incomplete", frame, "status packet without ERR byte")
        return Packet(frame[ID_INDEX], STATUS, body[2:], body[1])
    return Packet(frame[ID_INDEX], body[0], body[1:])


def find_frame(buf: bytearray) -> bytes | None:
    """Remove and return the next complete frame from a receive buffer (garbage before it dropped).

    Returns None while a frame is still incomplete. A header followed by FD (a stuffed sequence) or
    a non-zero reserved byte is not a frame start.
    """
    while True:
        i = buf.find(HEADER)
        if i < 0:
            del buf[:max(0, len(buf) - 2)]  # keep a possible partial header
            return None
        del buf[:i]
        if len(buf) < 4:
            return None
        if buf[len(HEADER)] != RESERVED:
            del buf[:1]
            continue
        total = frame_length(buf)
        if total is None or len(buf) < total:
            return None
        frame = bytes(buf[:total])
        del buf[:total]
        return frame


# ----- faults a simulated servo injects into its status packets ---------------------------------
def corrupt_crc(frame: bytes) -> bytes:
    """``frame`` with its CRC's high byte flipped (a bit error on the line)."""
    frame = bytes(frame)
    return frame[:-1] + bytes([frame[-1] ^ 0xFF])


def drop_error_byte(frame: bytes) -> bytes:
    """A status packet whose ERR byte was lost on the line: LEN promises one byte more than comes."""
    frame = bytes(frame)
    return frame[:ERROR_INDEX] + frame[ERROR_INDEX + 1:]
