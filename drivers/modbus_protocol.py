"""Modbus frames in one place: the RTU CRC, the exception codes, frame checks and frame faults.

pymodbus builds and parses the frames; the driver checks here why a reply was refused, and the
simulated drive damages its replies here, so every injected fault is one the driver recognises::

    RTU ADU   unit | PDU: function, data                    | CRC_L CRC_H (CRC-16/MODBUS)
    TCP ADU   TID_H TID_L | 00 00 | LEN_H LEN_L | unit      | PDU: function, data
    exception PDU: function | 0x80, exception code
"""
from __future__ import annotations

from pymodbus.constants import ExcCodes

# ----- byte groups of a TCP frame (the MBAP header) ---------------------------------------------
MBAP_TRANSACTION = slice(0, 2)  # echoed by the server
MBAP_PROTOCOL = slice(2, 4)     # always 0 for Modbus
MBAP_LENGTH = slice(4, 6)       # bytes that follow: unit id + PDU
MBAP_SIZE = 7                   # header including the unit id; the PDU starts here
PROTOCOL_ID = b"\x00\x00"
# ----- byte groups of an RTU frame --------------------------------------------------------------
RTU_CRC_SIZE = 2
RTU_MIN_SIZE = 4                # unit, function, CRC
EXCEPTION_BIT = 0x80            # set in the function code of an exception response

EXCEPTION_TEXT = {  # Modbus Application Protocol V1.1b3, section 7
    ExcCodes.ILLEGAL_FUNCTION: "illegal function",
    ExcCodes.ILLEGAL_ADDRESS: "illegal data address",
    ExcCodes.ILLEGAL_VALUE: "illegal data value",
    ExcCodes.DEVICE_FAILURE: "server device failure",
    ExcCodes.ACKNOWLEDGE: "acknowledge",
    ExcCodes.DEVICE_BUSY: "server device busy",
    ExcCodes.MEMORY_PARITY_ERROR: "memory parity error",
    ExcCodes.GATEWAY_PATH_UNAVIABLE: "gateway path unavailable",
    ExcCodes.GATEWAY_NO_RESPONSE: "gateway target failed to respond",
}


def describe_exception(code) -> str:
    """Readable exception response: ``'exception 2: illegal data address'``."""
    try:
        text = EXCEPTION_TEXT[ExcCodes(code)]
    except (ValueError, KeyError, TypeError):
        text = "unknown"
    return f"exception {code}: {text}"


# ----- CRC-16/MODBUS (polynomial 0xA001 reflected, init 0xFFFF), sent low byte first ----------
def modbus_crc(frame: bytes) -> int:
    """The RTU CRC of ``frame`` (unit id to the last data byte); ``to_bytes(2, "little")`` is what is sent."""
    crc = 0xFFFF
    for byte in frame:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(frame: bytes) -> bytes:
    """An RTU frame: ``frame`` (unit id, PDU) followed by its CRC, low byte first."""
    return bytes(frame) + modbus_crc(frame).to_bytes(RTU_CRC_SIZE, "little")


# ----- checks of a received frame ---------------------------------------------------------------
class FrameError(ValueError):
    """A received frame that cannot be used: ``kind`` is "crc", "protocol_id" or "truncated"."""

    def __init__(self, kind: str, frame: bytes, text: str) -> None:
        self.kind, self.frame = kind, bytes(frame)
        super().__init__(text)


def check_rtu_frame(frame: bytes) -> None:
    """Raise FrameError("crc") unless ``frame`` is long enough and ends with its own CRC."""
    frame = bytes(frame)
    if len(frame) < RTU_MIN_SIZE or with_crc(frame[:-RTU_CRC_SIZE]) != frame:
        raise FrameError("crc", frame, "reply CRC mismatch")


def check_tcp_frame(frame: bytes) -> None:
    """Raise FrameError when the MBAP header is wrong ("protocol_id") or promises more bytes than
    arrived ("truncated"). A frame shorter than the header is left to the caller."""
    frame = bytes(frame)
    if len(frame) < MBAP_LENGTH.stop:
        return
    if frame[MBAP_PROTOCOL] != PROTOCOL_ID:
        raise FrameError("protocol_id", frame, "MBAP protocol id is not 0")
    if len(frame) < MBAP_LENGTH.stop + int.from_bytes(frame[MBAP_LENGTH], "big"):
        raise FrameError("truncated", frame, "truncated frame: fewer bytes than the MBAP length")


# ----- faults a simulated device injects into its replies ---------------------------------------
def corrupt_checksum(frame: bytes, rtu: bool) -> bytes:
    """``frame`` with a wrong check: RTU flips the CRC's high byte; TCP has no checksum, so the
    MBAP protocol id is made non-zero instead (what a damaged TCP frame looks like)."""
    frame = bytes(frame)
    if rtu:
        return frame[:-1] + bytes([frame[-1] ^ 0xFF])
    return frame[:MBAP_PROTOCOL.start] + b"\x00\x01" + frame[MBAP_PROTOCOL.stop:]


def drop_last_byte(frame: bytes) -> bytes:
    """``frame`` without its last byte (a byte lost on the line)."""
    return bytes(frame)[:-1]
