"""Newport SMC100CC/PP RS-232 ASCII protocol: command lines, replies, TS and TE decoding, as data.

A command is ``nnAAxx`` + CR LF (PROTOCOLS.md section 2). Shared by the driver and the simulated
controller.
"""
from __future__ import annotations

import enum
import re
from dataclasses import dataclass

TERMINATOR = b"\r\n"
DEFAULT_BAUD = 57600


class Cmd(str, enum.Enum):
    """The two-letter commands goniofrost uses (the manual has more)."""

    MOVE_ABSOLUTE = "PA"
    MOVE_RELATIVE = "PR"
    TELL_POSITION = "TP"
    TELL_SETPOINT = "TH"
    TELL_STATE = "TS"
    HOME = "OR"
    STOP = "ST"
    VELOCITY = "VA"
    ACCELERATION = "AC"
    LIMIT_NEGATIVE = "SL"
    LIMIT_POSITIVE = "SR"
    ENABLE_STATE = "MM"
    TELL_ERROR = "TE"
    TELL_ERROR_STRING = "TB"
    VERSION = "VE"
    STAGE_ID = "ID"
    MOTION_TIME = "PT"


class State(enum.IntEnum):
    """Controller states as the two hex digits ``ef`` of a TS reply."""

    NOT_REFERENCED_FROM_RESET = 0x0A
    NOT_REFERENCED_FROM_HOMING = 0x0B
    NOT_REFERENCED_FROM_CONFIGURATION = 0x0C
    NOT_REFERENCED_FROM_DISABLE = 0x0D
    NOT_REFERENCED_FROM_READY = 0x0E
    NOT_REFERENCED_FROM_MOVING = 0x0F
    STAGE_ERROR = 0x10
    CONFIGURATION = 0x14
    HOMING = 0x1E
    MOVING = 0x28
    READY_FROM_HOMING = 0x32
    READY_FROM_MOVING = 0x33
    READY_FROM_DISABLE = 0x34
    DISABLE_FROM_READY = 0x3C
    DISABLE_FROM_MOVING = 0x3D


NOT_REFERENCED_STATES = frozenset(s for s in State if 0x0A <= s <= 0x0F)
READY_STATES = frozenset({State.READY_FROM_HOMING, State.READY_FROM_MOVING, State.READY_FROM_DISABLE})
DISABLE_STATES = frozenset({State.DISABLE_FROM_READY, State.DISABLE_FROM_MOVING})
MOTION_STATES = frozenset({State.HOMING, State.MOVING})

class ErrorBit(enum.IntFlag):
    """TS error bits (the four hex digits ``abcd``); reading TS clears them on the controller."""

    NEGATIVE_END_OF_RUN = 1 << 0
    POSITIVE_END_OF_RUN = 1 << 1
    PEAK_CURRENT = 1 << 2
    RMS_CURRENT = 1 << 3
    SHORT_CIRCUIT = 1 << 4
    FOLLOWING_ERROR = 1 << 5
    HOMING_TIMEOUT = 1 << 6
    WRONG_STAGE = 1 << 7
    DC_VOLTAGE_LOW = 1 << 8
    OUTPUT_POWER = 1 << 9


TS_ERROR_BITS = {  # error bit -> readable cause, lowest bit first
    ErrorBit.NEGATIVE_END_OF_RUN: "negative end of run",
    ErrorBit.POSITIVE_END_OF_RUN: "positive end of run",
    ErrorBit.PEAK_CURRENT: "peak current limit",
    ErrorBit.RMS_CURRENT: "RMS current limit",
    ErrorBit.SHORT_CIRCUIT: "short circuit detection",
    ErrorBit.FOLLOWING_ERROR: "following error",
    ErrorBit.HOMING_TIMEOUT: "homing time-out",
    ErrorBit.WRONG_STAGE: "wrong ESP stage",
    ErrorBit.DC_VOLTAGE_LOW: "DC voltage too low",
    ErrorBit.OUTPUT_POWER: "80 W output power exceeded",
}


class ErrorLetter(str, enum.Enum):
    """The letter TE returns for the last command ('@': no error); cleared once read."""

    NONE = "@"
    UNKNOWN_COMMAND = "A"
    BAD_ADDRESS = "B"
    PARAMETER = "C"
    NOT_ALLOWED = "D"
    HOME_STARTED = "E"
    OUT_OF_LIMITS = "G"
    IN_NOT_REFERENCED = "H"
    IN_CONFIGURATION = "I"
    IN_DISABLE = "J"
    IN_READY = "K"
    IN_HOMING = "L"
    IN_MOVING = "M"
    OUT_OF_SOFT_LIMIT = "N"
    TIMEOUT = "S"
    EEPROM = "U"
    EXECUTION = "V"


TE_LETTERS = {
    ErrorLetter.NONE: "no error",
    ErrorLetter.UNKNOWN_COMMAND: "unknown message code or floating point controller address",
    ErrorLetter.BAD_ADDRESS: "controller address not correct",
    ErrorLetter.PARAMETER: "parameter missing or out of range",
    ErrorLetter.NOT_ALLOWED: "command not allowed",
    ErrorLetter.HOME_STARTED: "home sequence already started",
    ErrorLetter.OUT_OF_LIMITS: "displacement out of limits",
    ErrorLetter.IN_NOT_REFERENCED: "command not allowed in NOT REFERENCED state",
    ErrorLetter.IN_CONFIGURATION: "command not allowed in CONFIGURATION state",
    ErrorLetter.IN_DISABLE: "command not allowed in DISABLE state",
    ErrorLetter.IN_READY: "command not allowed in READY state",
    ErrorLetter.IN_HOMING: "command not allowed in HOMING state",
    ErrorLetter.IN_MOVING: "command not allowed in MOVING state",
    ErrorLetter.OUT_OF_SOFT_LIMIT: "current position out of software limit",
    ErrorLetter.TIMEOUT: "communication time-out",
    ErrorLetter.EEPROM: "error during EEPROM access",
    ErrorLetter.EXECUTION: "error during command execution",
}

QUERY = "?"          # the argument of a query: ``1VA?``
MM_DISABLE = "0"     # MM0: READY -> DISABLE
MM_ENABLE = "1"      # MM1: DISABLE -> READY

# One command line: address, two letters, the rest (value, '?' or nothing); blanks ignored.
_LINE = re.compile(r"^(\d{1,2})([A-Za-z]{2})(.*)$")


def format_value(value: float) -> str:
    """Render a number the way the controller accepts it: '.' decimal point, no exponent."""
    text = f"{float(value):.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def build_command(address: int, cmd: Cmd | str, value: float | str | None = None) -> bytes:
    """Return the bytes of one command line, e.g. ``build_command(1, Cmd.MOVE_ABSOLUTE, 10)`` -> ``b'1PA10\\r\\n'``.

    ``value`` is a number (formatted with ``format_value``), a string such as ``'?'``, or None.
    """
    if not 1 <= int(address) <= 31:
        raise ValueError(f"SMC100 address must be 1-31, got {address!r}")
    letters = Cmd(cmd).value if not isinstance(cmd, Cmd) else cmd.value
    if value is None:
        arg = ""
    elif isinstance(value, str):
        arg = value
    else:
        arg = format_value(value)
    return f"{int(address)}{letters}{arg}".encode("ascii") + TERMINATOR


@dataclass(frozen=True)
class CommandLine:
    """One parsed command line: address, upper-case letters, argument text ('' if none)."""

    address: int
    letters: str
    argument: str

    @property
    def is_query(self) -> bool:
        return self.argument == QUERY


def parse_command(line: bytes) -> CommandLine | None:
    """Parse one received line (without CR LF); None when it is not a command at all."""
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return None
    match = _LINE.match(text.replace(" ", "").replace("\t", ""))
    if not match:
        return None
    return CommandLine(int(match.group(1)), match.group(2).upper(), match.group(3))


def build_reply(address: int, letters: str, value: str) -> bytes:
    """Return a reply line: the echoed prefix then the value, e.g. ``b'1TP10.5\\r\\n'``."""
    return f"{int(address)}{letters}{value}".encode("ascii") + TERMINATOR


def parse_reply(line: bytes, address: int, cmd: Cmd | str) -> str:
    """Return the value text of a reply line after checking its echoed prefix.

    ``line`` may end with CR LF. Raises ValueError when the prefix does not match.
    """
    text = line.decode("ascii", errors="replace").strip()
    prefix = f"{int(address)}{Cmd(cmd).value}"
    if not text.upper().startswith(prefix):
        raise ValueError(f"expected a reply starting with {prefix!r}, got {text!r}")
    return text[len(prefix):]


@dataclass(frozen=True)
class TellState:
    """A decoded TS reply: the error bits as readable causes and the controller state."""

    error_bits: int
    state: State

    @property
    def causes(self) -> list[str]:
        """Readable causes of the error bits that are set, lowest bit first."""
        return [text for bit, text in TS_ERROR_BITS.items() if self.error_bits & bit]

    @property
    def is_fault(self) -> bool:
        """True when the stage reports an error state or any error bit."""
        return self.state == State.STAGE_ERROR or self.error_bits != 0


def encode_ts(error_bits: int, state: State | int) -> str:
    """Return the six hex digits ``abcdef`` of a TS reply (upper case)."""
    return f"{int(error_bits):04X}{int(state):02X}"


def decode_ts(value: str) -> TellState:
    """Decode the six hex digits of a TS reply; ValueError on anything else."""
    if not re.fullmatch(r"[0-9A-Fa-f]{6}", value):
        raise ValueError(f"expected six hex digits after TS, got {value!r}")
    return TellState(int(value[:4], 16), State(int(value[4:], 16)))


# Identity of the simulated controller and stage; VE replies "<model> <firmware>" (QMI reads words 1, 2).
CONTROLLER_MODEL = "SMC100CC"
FIRMWARE_VERSION = "2.0.0"
STAGE_ID = "URS100CC"   # a Newport rotation stage the SMC100CC drives


def te_text(letter: str) -> str:
    """TB's reply value for a TE letter: the letter, a blank, the meaning in capitals (``G DISPLACEMENT
    OUT OF LIMITS``), the way drivers split it at the first blank."""
    return f"{letter} {te_meaning(letter).upper()}"


def te_meaning(letter: str) -> str:
    """Readable meaning of a TE error letter (unknown letters say so)."""
    try:
        return TE_LETTERS[ErrorLetter(letter)]
    except ValueError:
        return f"unknown error letter {letter!r}"
