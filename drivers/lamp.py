"""The lamp: on/off on a Modbus coil and a monitor photodiode on an input register.

The lamp usually sits on a motor drive's Modbus device (rig file: ``device: camera_arm``) and
then shares that axis's connection; it may also have its own host and port.
"""
from __future__ import annotations

from collections.abc import Mapping

from .errors import DeviceError, NotConnectedError
from .modbus_drive import ModbusAxis, ModbusLink

DEFAULT_FULL_SCALE = 50_000  # photodiode counts at nominal intensity (1.0)


class Lamp:
    """Switch the lamp and read its monitor photodiode relative to nominal.

    ``link``: the ModbusLink to use; ``owns_link``: whether ``close()`` closes it (False when the
    link belongs to an axis); ``coil``: on/off coil address; ``photodiode_register``: input
    register address; ``full_scale``: counts that read as 1.0.
    """

    def __init__(self, link: ModbusLink, coil: int = 0, photodiode_register: int = 0x0200,
                 full_scale: float = DEFAULT_FULL_SCALE, owns_link: bool = True, name: str = "lamp") -> None:
        self.link, self.owns_link, self.name = link, owns_link, name
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
            return cls(axis.link, owns_link=False, **common)
        if section.get("protocol") == "modbus-rtu":
            link = ModbusLink("lamp", section.get("device_id", 1), None, section["port"],
                              section.get("baud", 115200), section.get("parity", "E"))
        else:
            link = ModbusLink("lamp", section.get("device_id", 1), section.get("host", "127.0.0.1"),
                              section["port"])
        return cls(link, **common)

    def connect(self) -> None:
        """Open the link if nobody has yet, and check the coil answers."""
        self.link.open()
        self._connected = True
        self.is_on()

    def close(self) -> None:
        """Forget the connection; close the link only if this lamp owns it."""
        if self._connected and self.owns_link:
            self.link.close()
        self._connected = False

    def _require(self, command: str) -> None:
        if not self._connected:
            raise NotConnectedError(self.name, command)

    def on(self) -> None:
        """Switch the lamp on (coil = 1)."""
        self._require("on")
        self.link.call(f"write coil {self.coil} on", "write_coil", self.coil, True)

    def off(self) -> None:
        """Switch the lamp off (coil = 0)."""
        self._require("off")
        self.link.call(f"write coil {self.coil} off", "write_coil", self.coil, False)

    def is_on(self) -> bool:
        """The coil state as the device reports it."""
        self._require("is_on")
        return bool(self.link.call(f"read coil {self.coil}", "read_coils", self.coil, count=1).bits[0])

    def photodiode(self) -> float:
        """Monitor photodiode reading relative to nominal (counts / full_scale; 0 when off)."""
        self._require("photodiode")
        rr = self.link.call(f"read input 0x{self.photodiode_register:04X}", "read_input_registers",
                            self.photodiode_register, count=1)
        return rr.registers[0] / self.full_scale
