"""Modbus register maps of motor drives, as data: named maps and inline maps from the rig file.

The default ``oriental-az`` follows PROTOCOLS.md section 3. Values are 32 bits in two holding
registers (``word_order`` "big" or "little"); addresses are 0-based PDU addresses. A rig file
names a map or gives one inline (``register_map: {base: oriental-az, feedback_position: 0x0120}``).
"""
from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from dataclasses import dataclass, field

from goniofrost.core.config_check import ABSENT, Key, check_section, is_int, is_mapping, is_text, join
from goniofrost.core.errors import ConfigError

WORD_ORDERS = ("big", "little")
DIRECT_DATA_REGISTERS = 16  # one move = one write of 8 x 32-bit values


class DirectData:
    """Offsets (in 32-bit values) of the direct-data block, in the order of the one write."""

    OPERATION_NO = 0   # operation data No. (0)
    OPERATION_TYPE = 1  # 1 absolute, 2 incremental
    POSITION = 2       # steps
    SPEED = 3          # Hz = steps/s
    RATE = 4           # starting/changing rate, 0.001 kHz/s = steps/s^2
    STOP_RATE = 5      # stopping deceleration, same unit
    CURRENT = 6        # operating current, 0.1 %
    TRIGGER = 7        # 1 = take all data: starts the move


class OperationType(enum.IntEnum):
    """The direct-data operation type (``DirectData.OPERATION_TYPE``)."""

    ABSOLUTE = 1
    INCREMENTAL = 2


TRIGGER_ALL_DATA = 1
# An interlock wired to a discrete input of a drive (read with function 02; the address is the
# rig file's suspenders.interlock.input): this value means closed, safe to run; the other, open.
INTERLOCK_CLOSED = 1
FULL_CURRENT = 1000  # 100.0 %


class InputBit(str, enum.Enum):
    """Bits of the driver input command (lower word of ``input_command``); the values are the
    names a rig file uses in ``register_map.input_bits``."""

    START = "start"
    ZHOME = "zhome"      # return to home
    STOP = "stop"        # decelerate to a stop
    FREE = "free"        # de-energise the motor
    ALM_RST = "alm_rst"  # reset the alarm (once its cause has gone)


class OutputBit(str, enum.Enum):
    """Bits of the driver output status (lower word of ``output_status``); the values are the
    names a rig file uses in ``register_map.output_bits``."""

    READY = "ready"
    ALM_A = "alm_a"      # alarm present: the alarm code register says which
    SYS_BSY = "sys_bsy"
    MOVE = "move"        # the motor is running
    IN_POS = "in_pos"

# Oriental Motor AZ alarm codes (AZ operating manual, alarm list; only the common ones).
AZ_ALARM_CODES = {
    0x10: "excessive position deviation",
    0x20: "overcurrent",
    0x21: "main circuit overheat",
    0x22: "overvoltage",
    0x25: "undervoltage",
    0x30: "overload",
    0x31: "overspeed",
    0x41: "EEPROM error",
    0x42: "sensor error at power-on",
    0x60: "both limit sensors active",
    0x66: "hardware overtravel",
    0x67: "software overtravel",
}


@dataclass(frozen=True)
class RegisterMap:
    """Where a drive keeps what goniofrost needs (PDU addresses of the first of two registers).

    ``input_bits``: bit numbers in the lower word of ``input_command`` (start, zhome, stop,
    free, alm_rst). ``output_bits``: bit numbers in the lower word of ``output_status`` (ready,
    alm_a, sys_bsy, move, in_pos). ``alarm_codes``: code -> readable cause.
    """

    name: str
    direct_data: int
    input_command: int
    output_status: int
    alarm_code: int
    feedback_position: int
    command_position: int
    input_bits: Mapping[InputBit, int] = field(default_factory=dict)
    output_bits: Mapping[OutputBit, int] = field(default_factory=dict)
    alarm_codes: Mapping[int, str] = field(default_factory=dict)

    def alarm_text(self, code: int) -> str:
        """Readable alarm: ``'alarm 0x30: overload'``."""
        return f"alarm 0x{code:02X}: {self.alarm_codes.get(code, 'see the drive manual')}"

    def highest_holding_register(self) -> int:
        """The last holding register address the map uses."""
        starts = (self.direct_data + DIRECT_DATA_REGISTERS - 2, self.input_command,
                  self.output_status, self.alarm_code, self.feedback_position, self.command_position)
        return max(starts) + 1


ORIENTAL_AZ = RegisterMap(
    name="oriental-az",
    direct_data=0x0058,
    input_command=0x007C,
    output_status=0x007E,
    alarm_code=0x0080,
    feedback_position=0x0120,  # unverified in the manual (third-party code); keep overridable
    command_position=0x0122,
    input_bits={InputBit.START: 3, InputBit.ZHOME: 4, InputBit.STOP: 5, InputBit.FREE: 6, InputBit.ALM_RST: 7},
    output_bits={OutputBit.READY: 5, OutputBit.ALM_A: 7, OutputBit.SYS_BSY: 8, OutputBit.MOVE: 13,
                 OutputBit.IN_POS: 14},
    alarm_codes=AZ_ALARM_CODES,
)

NAMED_MAPS: dict[str, RegisterMap] = {ORIENTAL_AZ.name: ORIENTAL_AZ}
_ADDRESS_KEYS = ("direct_data", "input_command", "output_status", "alarm_code",
                 "feedback_position", "command_position")
_BIT_KEYS: dict[str, type[enum.Enum]] = {"input_bits": InputBit, "output_bits": OutputBit}


def resolve_map(spec, source: str = "rig", keypath: str = "driver.register_map") -> RegisterMap:
    """Return the RegisterMap for a rig-file value: a map name or an inline mapping.

    Raises ConfigError naming ``source`` and ``keypath`` for unknown names, unknown keys,
    missing keys (inline maps without ``base``) and addresses outside 0-65534.
    """
    if isinstance(spec, RegisterMap):
        return spec
    if isinstance(spec, str):
        if spec not in NAMED_MAPS:
            raise ConfigError(source, keypath, f"one of {sorted(NAMED_MAPS)} or a mapping", spec)
        return NAMED_MAPS[spec]
    if not isinstance(spec, Mapping):
        raise ConfigError(source, keypath, "a register map name or a mapping", spec)
    return _inline_map(spec, source, keypath)


def _is_address(value) -> bool:
    return is_int(value) and 0 <= value <= 0xFFFE


def _bits_table(bit_enum: type[enum.Enum]) -> dict:
    return {member.value: Key(lambda v: is_int(v) and 0 <= v <= 15, "a bit number 0..15", ABSENT) for member in bit_enum}


# An inline map's keys: each address may be left out when a ``base`` map gives it.
_INLINE_KEYS = {
    "base": Key(lambda v: True, "a register map name or a mapping", ABSENT),
    "name": Key(is_text, "a name for the map", ABSENT),
    **{key: Key(_is_address, "an integer register address 0..0xFFFE", ABSENT) for key in _ADDRESS_KEYS},
    **{key: Key(is_mapping, f"a mapping of {tuple(m.value for m in bits)} to bit numbers", {},
                nested=lambda v, source, kp, bits=bits: check_section(v, _bits_table(bits), source, kp))
       for key, bits in _BIT_KEYS.items()},
}


def _inline_map(spec: Mapping, source: str, keypath: str) -> RegisterMap:
    checked = check_section(spec, _INLINE_KEYS, source, keypath)
    base = resolve_map(checked["base"], source, join(keypath, "base")) if "base" in checked else None
    values: dict = dataclasses.asdict(base) if base else {"alarm_codes": {}}
    values["name"] = str(checked.get("name", "inline"))
    for key in _ADDRESS_KEYS:
        if key in checked:
            values[key] = checked[key]
        elif key not in values:
            raise ConfigError(source, join(keypath, key), "a register address (or a 'base' map)", "nothing")
    for key, bit_enum in _BIT_KEYS.items():
        values[key] = {**values.get(key, {}), **{bit_enum(name): bit for name, bit in checked[key].items()}}
    return RegisterMap(**values)


# ----- 32-bit values in two 16-bit registers ---------------------------------------------------
def to_registers(value: int, word_order: str = "big") -> list[int]:
    """Two registers holding a signed 32-bit value (two's complement): -1000 -> [0xFFFF, 0xFC18]."""
    value = int(value)
    if not -(1 << 31) <= value < (1 << 32):
        raise ValueError(f"{value} does not fit in 32 bits")
    raw = value & 0xFFFFFFFF
    words = [raw >> 16, raw & 0xFFFF]
    return words if _order(word_order) == "big" else words[::-1]


def from_registers(words, word_order: str = "big", signed: bool = True) -> int:
    """The 32-bit value of two registers (signed by default)."""
    hi, lo = (words[0], words[1]) if _order(word_order) == "big" else (words[1], words[0])
    raw = (int(hi) << 16) | int(lo)
    return raw - (1 << 32) if signed and raw >= (1 << 31) else raw


def _order(word_order: str) -> str:
    if word_order not in WORD_ORDERS:
        raise ValueError(f"word_order must be one of {WORD_ORDERS}, got {word_order!r}")
    return word_order


def direct_data_registers(position_steps: int, speed_hz: int, rate: int, stop_rate: int,
                          word_order: str = "big", operation_type: int = OperationType.ABSOLUTE,
                          current: int = FULL_CURRENT) -> list[int]:
    """The 16 registers of one direct-data move, ending with trigger = 1 (starts the move)."""
    values = [0, operation_type, position_steps, speed_hz, rate, stop_rate, current, TRIGGER_ALL_DATA]
    return [word for v in values for word in to_registers(v, word_order)]
