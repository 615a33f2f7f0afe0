"""Newport SMC100CC/PP RS-232 ASCII protocol: command lines, replies, TS and TE decoding, as data.

Source: SMC100CC & SMC100PP user manual (EDH0206En2054), summarised in PROTOCOLS.md section 2.
A command is ``nnAAxx`` + CR LF: ``nn`` the controller address (1-31), ``AA`` two letters, ``xx``
a value, ``?`` or nothing. Queries echo their prefix (``1VA?`` -> ``1VA10``); set commands reply
nothing; a rejected command replies nothing and stores an error letter read back with ``TE``.
Shared by the driver (``drivers/smc100.py``) and the simulated controller (``sim/smc100.py``).
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

# TS error bits (the four hex digits ``abcd``), bit number -> readable cause.
TS_ERROR_BITS = {
    0: "negative end of run",
    1: "positive end of run",
    2: "peak current limit",
    3: "RMS current limit",
    4: "short circuit detection",
    5: "following error",
    6: "homing time-out",
    7: "wrong ESP stage",
    8: "DC voltage too low",
    9: "80 W output power exceeded",
}

# TE error letters -> meaning ('@' means no error).
TE_LETTERS = {
    "@": "no error",
    "A": "unknown message code or floating point controller address",
    "B": "controller address not correct",
    "C": "parameter missing or out of range",
    "D": "command not allowed",
    "E": "home sequence already started",
    "G": "displacement out of limits",
    "H": "command not allowed in NOT REFERENCED state",
    "I": "command not allowed in CONFIGURATION state",
    "J": "command not allowed in DISABLE state",
    "K": "command not allowed in READY state",
    "L": "command not allowed in HOMING state",
    "M": "command not allowed in MOVING state",
    "N": "current position out of software limit",
    "S": "communication time-out",
    "U": "error during EEPROM access",
    "V": "error during command execution",
}

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
        return self.argument == "?"


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
        return [text for bit, text in TS_ERROR_BITS.items() if self.error_bits >> bit & 1]

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


def te_meaning(letter: str) -> str:
    """Readable meaning of a TE error letter (unknown letters say so)."""
    return TE_LETTERS.get(letter, f"unknown error letter {letter!r}")
