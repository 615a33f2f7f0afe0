"""The lamp: on/off on a Modbus coil and a monitor photodiode on an input register.

It shares a motor drive's connection (``device: AXIS``) or has its own host and port.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping

from .errors import ChecksumError, DeviceError, DeviceTimeout, NotConnectedError, ProtocolError
from .modbus_drive import REPLY_TIMEOUT_S, ModbusAxis, ModbusLink

log = logging.getLogger(__name__)
DEFAULT_FULL_SCALE = 50_000  # photodiode counts at nominal intensity (1.0)
DEFAULT_RETRIES = 2


class Lamp:
    """Switch the lamp and read its monitor photodiode relative to nominal.

    ``link``: the ModbusLink to use; ``owns_link``: whether ``close()`` closes it (False when the
    link belongs to an axis); ``coil``: on/off coil address; ``photodiode_register``: input
    register address; ``full_scale``: counts that read as 1.0; ``retries``: extra attempts after a
    reply timeout or a damaged reply (every lamp request is safe to repeat: reads, and a coil set
    to the state it should have; the host axis's ``retries`` when it shares that axis's link).
    """

    def __init__(self, link: ModbusLink, coil: int = 0, photodiode_register: int = 0x0200,
                 full_scale: float = DEFAULT_FULL_SCALE, owns_link: bool = True, name: str = "lamp",
                 retries: int = DEFAULT_RETRIES) -> None:
        self.link, self.owns_link, self.name = link, owns_link, name
        self.retries = int(retries)
        self.coil, self.photodiode_register = int(coil), int(photodiode_register)
        self.full_scale = float(full_scale)
        self._connected = False

    @classmethod
    def from_section(cls, section: Mapping, axes: Mapping | None = None) -> "Lamp":
        """Build from a validated lamp driver section; ``device`` names a Modbus axis in ``axes``."""
        common = dict(coil=section.get("coil", 0),
                      photodiode_register=section.get("photodiode_register", 0x0200),
                      full_scale=section.get("full_scale", DEFAULT_FULL_SCALE))
        if "device" in section:
            axis = (axes or {}).get(section["device"])
            if not isinstance(axis, ModbusAxis):
                raise DeviceError("lamp", "connect", None,
                                  f"device {section['device']!r} is not a Modbus axis of this rig")
            return cls(axis.link, owns_link=False, retries=axis.config.retries, **common)
        rtu = section.get("protocol") == "modbus-rtu"
        where = section["port"] if rtu else f"{section.get('host', '127.0.0.1')}:{section['port']}"
        link = ModbusLink("lamp", section.get("device_id", 1), rtu,
                          section.get("reply_timeout_ms", REPLY_TIMEOUT_S * 1000.0) / 1000.0, where)
        return cls(link, **common)

    def connect(self, transport=None) -> None:
        """Check the coil answers: on the link of the axis it shares, or on ``transport`` (its own
        connection, opened by the rig layer; the lamp owns it from now on)."""
        if transport is not None:
            self.link.open(transport)
        elif not self.link.is_open:
            raise NotConnectedError(self.name, "connect (no connection: its axis first, or its own port)")
        self._connected = True
        try:
            self.is_on()
        except BaseException:
            self.close()  # its own connection is closed; a shared one stays with its axis
            raise

    def close(self) -> None:
        """Forget the connection; close the link only if this lamp owns it."""
        if self._connected and self.owns_link:
            self.link.close()
        self._connected = False

    def _require(self, command: str) -> None:
        if not self._connected:
            raise NotConnectedError(self.name, command)

    def _call(self, text: str, method: str, *args, **kwargs):
        """One request, repeated after a reply timeout or a damaged reply up to ``retries`` times
        (each retry logged: the session's device log)."""
        for attempt in range(self.retries + 1):
            try:
                return self.link.call(text, method, *args, **kwargs)
            except (DeviceTimeout, ChecksumError, ProtocolError) as exc:
                if attempt == self.retries:
                    raise
                log.info("%s: %s: retry %d of %d after %s", self.name, text, attempt + 1, self.retries, exc)

    def on(self) -> None:
        """Switch the lamp on (coil = 1)."""
        self._require("on")
        self._call(f"write coil {self.coil} on", "write_coil", self.coil, True)

    def off(self) -> None:
        """Switch the lamp off (coil = 0)."""
        self._require("off")
        self._call(f"write coil {self.coil} off", "write_coil", self.coil, False)

    def is_on(self) -> bool:
        """The coil state as the device reports it."""
        self._require("is_on")
        return bool(self._call(f"read coil {self.coil}", "read_coils", self.coil, count=1).bits[0])

    def photodiode(self) -> float:
        """Monitor photodiode reading relative to nominal (counts / full_scale; 0 when off)."""
        self._require("photodiode")
        rr = self._call(f"read input 0x{self.photodiode_register:04X}", "read_input_registers",
                        self.photodiode_register, count=1)
        return rr.registers[0] / self.full_scale

    def identity(self) -> dict:
        """The lamp's device: protocol, device id, coil and photodiode register (read-only)."""
        self._require("identity")
        return {"protocol": "modbus-rtu" if self.link.rtu else "modbus-tcp",
                "device_id": self.link.device_id, "coil": self.coil,
                "photodiode_register": self.photodiode_register, "on": self.is_on()}
