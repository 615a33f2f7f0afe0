"""Validation of the ``driver`` sections of a rig file (each axis's, and the lamp's).

Key tables per protocol (``SCHEMAS``, ``LAMP_SCHEMAS``); a bad section raises one ``ConfigError``.
``port: sim`` (serial) and ``port: 0`` (TCP) are filled in by the simulator.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

from goniofrost.core.config_check import ABSENT as OPTIONAL
from goniofrost.core.config_check import Key, check_section, int_in as _int_in, is_bool as _bool
from goniofrost.core.config_check import is_text as _text, join, one_of as _one_of
from goniofrost.core.errors import ConfigError


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def _map_name_or_mapping(v) -> bool:
    return _text(v) or isinstance(v, Mapping)


SERIAL_PORT = Key(_text, 'a serial device path (e.g. /dev/ttyUSB0) or "sim"')
TCP_PORT = Key(_int_in(0, 65535), "a TCP port 1-65535 (0: picked by the simulator)")
BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1_000_000, 2_000_000,
         3_000_000, 4_000_000, 4_500_000)
RETRIES = Key(_int_in(0, 10), "an integer 0-10 (extra attempts of an idempotent read after a reply "
              "timeout or a damaged reply; default 2)", OPTIONAL)
REPLY_TIMEOUT = Key(_positive, "a positive reply timeout in ms", OPTIONAL)

DYNAMIXEL = {
    "port": SERIAL_PORT,
    "id": Key(_int_in(0, 252), "a Dynamixel ID 0-252"),
    "baud": Key(_one_of(*BAUDS), f"a baud rate among {', '.join(map(str, BAUDS))}", OPTIONAL),
    "model": Key(_text, 'an X-series model name such as "XM430-W350"', OPTIONAL),
    "counts_per_deg": Key(_positive, "a positive number of encoder counts per degree (4096/360 direct)"),
    "reboot_after_fault": Key(_bool, "true or false", OPTIONAL),
    "reply_timeout_ms": REPLY_TIMEOUT,   # default 100 ms (the SDK's own: bytes x byte time + 34 ms)
    "retries": RETRIES,
}
MODBUS_COMMON = {
    "device_id": Key(_int_in(0, 247), "a Modbus device id 0-247", OPTIONAL),
    "steps_per_deg": Key(_positive, "a positive number of drive steps per degree"),
    "word_order": Key(_one_of("big", "little"), '"big" (high word first) or "little"', OPTIONAL),
    "register_map": Key(_map_name_or_mapping, "a register map name (e.g. oriental-az) or a mapping", OPTIONAL),
    "reply_timeout_ms": REPLY_TIMEOUT,   # default 300 ms
    "retries": RETRIES,
}
MODBUS_TCP = {"host": Key(_text, "a host name or address (127.0.0.1 for the simulator)"),
              "port": TCP_PORT, **MODBUS_COMMON}
MODBUS_RTU = {"port": SERIAL_PORT,
              "baud": Key(_one_of(*BAUDS), f"a baud rate among {', '.join(map(str, BAUDS))}", OPTIONAL),
              "parity": Key(_one_of("N", "E", "O"), '"N", "E" or "O"', OPTIONAL), **MODBUS_COMMON}
SMC100 = {
    "port": SERIAL_PORT,
    "address": Key(_int_in(1, 31), "a controller address 1-31", OPTIONAL),
    "baud": Key(_one_of(*BAUDS), "a baud rate (57600 on the SMC100)", OPTIONAL),
    "units_per_deg": Key(_positive, "a positive number of controller units per degree", OPTIONAL),
    "reply_timeout_ms": REPLY_TIMEOUT,   # default 200 ms (the manual: about 10 ms for TP)
    "retries": RETRIES,
}
SCHEMAS: dict[str, dict[str, Key]] = {"dynamixel": DYNAMIXEL, "modbus-tcp": MODBUS_TCP,
                                        "modbus-rtu": MODBUS_RTU, "smc100": SMC100}

LAMP_COMMON = {
    "device": Key(_text, "the name of the axis whose Modbus device hosts the lamp", OPTIONAL),
    "device_id": Key(_int_in(0, 247), "a Modbus device id 0-247", OPTIONAL),
    "coil": Key(_int_in(0, 65535), "a coil address 0-65535"),
    "photodiode_register": Key(_int_in(0, 65535), "an input register address 0-65535"),
    "full_scale": Key(_positive, "photodiode counts at nominal intensity (> 0)", OPTIONAL),
    "reply_timeout_ms": REPLY_TIMEOUT,   # its own connection's; default 300 ms
}
LAMP_SCHEMAS: dict[str, dict[str, Key]] = {
    "modbus-tcp": {**LAMP_COMMON, "host": Key(_text, "a host name or address", OPTIONAL),
                   "port": Key(_int_in(0, 65535), "a TCP port 0-65535", OPTIONAL)},
    "modbus-rtu": {**LAMP_COMMON, "port": Key(_text, "a serial device path or \"sim\"", OPTIONAL),
                   "baud": Key(_one_of(*BAUDS), "a baud rate", OPTIONAL),
                   "parity": Key(_one_of("N", "E", "O"), '"N", "E" or "O"', OPTIONAL)},
}


def validate_driver_section(section: Mapping, source: str, keypath: str) -> dict:
    """Check one driver section; ``keypath`` like "axes.sample_yaw.driver" or "lamp.driver".

    A keypath starting with "lamp" is checked against the lamp schemas. Returns the section as
    given (keys left out stay out: each driver has its own defaults). Raises ConfigError.
    """
    if not isinstance(section, Mapping):
        raise ConfigError(source, keypath, "a mapping with a protocol key", section)
    schemas = LAMP_SCHEMAS if keypath.split(".")[0] == "lamp" else SCHEMAS
    protocol = section.get("protocol")
    if protocol not in schemas:
        raise ConfigError(source, join(keypath, "protocol"), f"one of {', '.join(schemas)}", protocol)
    table = {"protocol": Key(_one_of(*schemas), f"one of {', '.join(schemas)}"), **schemas[protocol]}
    out = check_section(section, table, source, keypath, context=f"(protocol {protocol})")
    if "register_map" in section:  # a named map must exist; an inline map's own keys are checked too
        from .modbus_map import resolve_map
        resolve_map(section["register_map"], source, join(keypath, "register_map"))
    if keypath.split(".")[0] == "lamp" and "device" not in section and "port" not in section:
        raise ConfigError(source, join(keypath, "device"),
                          "either device (an axis hosting the lamp) or the lamp's own port", "neither")
    return out


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



def command_step_deg(section: Mapping) -> float:
    """Degrees between two positions a validated ``driver`` section's device can be commanded to:
    the drivers send round(deg x steps) (Modbus ``steps_per_deg``, Dynamixel ``counts_per_deg``:
    0.087890625 deg for 4096 counts a turn); 0 for the SMC100, whose PA takes six decimals of its
    units (finer than any cell). What the planner puts the joint targets on (``planner.steps``)."""
    protocol = section["protocol"]
    if protocol == "dynamixel":
        return 1.0 / float(section["counts_per_deg"])
    if protocol in ("modbus-tcp", "modbus-rtu"):
        return 1.0 / float(section["steps_per_deg"])
    return 0.0
