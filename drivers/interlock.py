"""An interlock input: one discrete input (Modbus function 02) of a motor drive.

Shares the drive's connection; ``modbus_map.INTERLOCK_CLOSED`` means closed (safe to run).
"""
from __future__ import annotations

from .errors import DeviceError
from .modbus_drive import ModbusAxis
from .modbus_map import INTERLOCK_CLOSED


class Interlock:
    """Read the interlock wired to discrete input ``address`` of the Modbus axis ``axis``."""

    def __init__(self, axis, address: int) -> None:
        if not isinstance(axis, ModbusAxis):
            raise DeviceError(getattr(axis, "name", "interlock"), "connect", None,
                              "the interlock's device is not a Modbus axis")
        self.link, self.address, self.name = axis.link, int(address), f"{axis.name} interlock"

    def is_closed(self) -> bool:
        """True when the input reads INTERLOCK_CLOSED (a device error when the drive does not answer)."""
        reply = self.link.call(f"read discrete input {self.address}", "read_discrete_inputs", self.address, count=1)
        return int(bool(reply.bits[0])) == INTERLOCK_CLOSED
