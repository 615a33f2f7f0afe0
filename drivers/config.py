"""Validation of the ``driver`` sections of a rig file (each axis's, and the lamp's).

Allowed keys per protocol are declared as data (``SCHEMAS``, ``LAMP_SCHEMAS``): key -> Field(check,
expected, required). Unknown keys, missing required keys and bad values raise
``ConfigError(source, keypath, expected, found)``. ``port: sim`` (serial) and ``port: 0`` (TCP)
mean "filled in by the simulator at run time".
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from goniofrost.core.errors import ConfigError


@dataclass(frozen=True)
class Field:
    """One allowed key: ``check(value) -> bool`` and the text of what it expects."""

    check: Callable[[Any], bool]
    expected: str
    required: bool = True


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _int_in(lo: int, hi: int) -> Callable[[Any], bool]:
    return lambda v: _is_int(v) and lo <= v <= hi


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def _text(v) -> bool:
    return isinstance(v, str) and v.strip() != ""


def _one_of(*values) -> Callable[[Any], bool]:
    return lambda v: v in values


def _bool(v) -> bool:
    return isinstance(v, bool)


def _map_name_or_mapping(v) -> bool:
    return _text(v) or isinstance(v, Mapping)


SERIAL_PORT = Field(_text, 'a serial device path (e.g. /dev/ttyUSB0) or "sim"')
TCP_PORT = Field(_int_in(0, 65535), "a TCP port 1-65535 (0: picked by the simulator)")
BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1_000_000, 2_000_000,
         3_000_000, 4_000_000, 4_500_000)
RETRIES = Field(_int_in(0, 10), "an integer 0-10 (extra attempts after a transient error)", False)

DYNAMIXEL = {
    "port": SERIAL_PORT,
    "id": Field(_int_in(0, 252), "a Dynamixel ID 0-252"),
    "baud": Field(_one_of(*BAUDS), f"a baud rate among {', '.join(map(str, BAUDS))}", False),
    "model": Field(_text, 'an X-series model name such as "XM430-W350"', False),
    "counts_per_deg": Field(_positive, "a positive number of encoder counts per degree (4096/360 direct)"),
    "reboot_after_fault": Field(_bool, "true or false", False),
    "reply_timeout_ms": Field(_positive, "a positive reply timeout in ms", False),
    "retries": RETRIES,
}
MODBUS_COMMON = {
    "device_id": Field(_int_in(0, 247), "a Modbus device id 0-247", False),
    "steps_per_deg": Field(_positive, "a positive number of drive steps per degree"),
    "word_order": Field(_one_of("big", "little"), '"big" (high word first) or "little"', False),
    "register_map": Field(_map_name_or_mapping, "a register map name (e.g. oriental-az) or a mapping", False),
    "retries": RETRIES,
}
MODBUS_TCP = {"host": Field(_text, "a host name or address (127.0.0.1 for the simulator)"),
              "port": TCP_PORT, **MODBUS_COMMON}
MODBUS_RTU = {"port": SERIAL_PORT,
              "baud": Field(_one_of(*BAUDS), f"a baud rate among {', '.join(map(str, BAUDS))}", False),
              "parity": Field(_one_of("N", "E", "O"), '"N", "E" or "O"', False), **MODBUS_COMMON}
SMC100 = {
    "port": SERIAL_PORT,
    "address": Field(_int_in(1, 31), "a controller address 1-31", False),
    "baud": Field(_one_of(*BAUDS), "a baud rate (57600 on the SMC100)", False),
    "units_per_deg": Field(_positive, "a positive number of controller units per degree", False),
    "retries": RETRIES,
}
SCHEMAS: dict[str, dict[str, Field]] = {"dynamixel": DYNAMIXEL, "modbus-tcp": MODBUS_TCP,
                                        "modbus-rtu": MODBUS_RTU, "smc100": SMC100}

LAMP_COMMON = {
    "device": Field(_text, "the name of the axis whose Modbus device hosts the lamp", False),
    "device_id": Field(_int_in(0, 247), "a Modbus device id 0-247", False),
    "coil": Field(_int_in(0, 65535), "a coil address 0-65535"),
    "photodiode_register": Field(_int_in(0, 65535), "an input register address 0-65535"),
    "full_scale": Field(_positive, "photodiode counts at nominal intensity (> 0)", False),
}
LAMP_SCHEMAS: dict[str, dict[str, Field]] = {
    "modbus-tcp": {**LAMP_COMMON, "host": Field(_text, "a host name or address", False),
                   "port": Field(_int_in(0, 65535), "a TCP port 0-65535", False)},
    "modbus-rtu": {**LAMP_COMMON, "port": Field(_text, "a serial device path or \"sim\"", False),
                   "baud": Field(_one_of(*BAUDS), "a baud rate", False),
                   "parity": Field(_one_of("N", "E", "O"), '"N", "E" or "O"', False)},
}


def _join(keypath: str, key: str) -> str:
    return f"{keypath}.{key}" if keypath else key


def validate_driver_section(section: Mapping, source: str, keypath: str) -> None:
    """Check one driver section; ``keypath`` like "axes.sample_yaw.driver" or "lamp.driver".

    A keypath starting with "lamp" is checked against the lamp schemas. Raises ConfigError.
    """
    if not isinstance(section, Mapping):
        raise ConfigError(source, keypath, "a mapping with a protocol key", section)
    schemas = LAMP_SCHEMAS if keypath.split(".")[0] == "lamp" else SCHEMAS
    protocol = section.get("protocol")
    if protocol not in schemas:
        raise ConfigError(source, _join(keypath, "protocol"), f"one of {', '.join(schemas)}", protocol)
    schema = schemas[protocol]
    for key in section:
        if key != "protocol" and key not in schema:
            raise ConfigError(source, _join(keypath, str(key)),
                              f"one of the keys protocol, {', '.join(schema)} (protocol {protocol})",
                              f"unknown key {key!r}")
    for key, spec in schema.items():
        if key not in section:
            if spec.required:
                raise ConfigError(source, _join(keypath, key), spec.expected, "nothing (key missing)")
        elif not spec.check(section[key]):
            raise ConfigError(source, _join(keypath, key), spec.expected, section[key])
    if "register_map" in section:  # a named map must exist; an inline map's own keys are checked too
        from .modbus_map import resolve_map
        resolve_map(section["register_map"], source, _join(keypath, "register_map"))
    if keypath.split(".")[0] == "lamp" and "device" not in section and "port" not in section:
        raise ConfigError(source, _join(keypath, "device"),
                          "either device (an axis hosting the lamp) or the lamp's own port", "neither")


LAMP_HOST_PROTOCOLS = ("modbus-tcp", "modbus-rtu")  # the lamp's coil and photodiode sit on a Modbus device


def check_lamp_host(lamp_driver: Mapping, axis_drivers: Mapping[str, Mapping], source: str) -> None:
    """A lamp ``device:`` must name an axis of the rig whose driver speaks Modbus (ConfigError otherwise).

    ``axis_drivers``: {axis name: its driver section}.
    """
    if not isinstance(lamp_driver, Mapping) or "device" not in lamp_driver:
        return
    device = lamp_driver["device"]
    keypath = "lamp.driver.device"
    if not isinstance(device, str) or device not in axis_drivers:
        raise ConfigError(source, keypath, f"the name of a Modbus axis of this rig ({', '.join(axis_drivers) or 'none'})",
                          device)
    driver = axis_drivers[device]
    protocol = driver.get("protocol") if isinstance(driver, Mapping) else None
    if protocol not in LAMP_HOST_PROTOCOLS:
        raise ConfigError(source, keypath, "an axis whose driver is modbus-tcp or modbus-rtu "
                          "(the lamp's coil and photodiode sit on a Modbus device)", f"{device} ({protocol})")


def check_lamp_against_rig(rig) -> None:
    """``check_lamp_host`` on a loaded rig (a rig-file check across sections)."""
    check_lamp_host((rig.lamp or {}).get("driver", {}), {n: a.driver for n, a in rig.axes.items()}, rig.source)
