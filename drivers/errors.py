"""Typed errors of every device driver: each names the axis, the command and what came back.

All derive from ``DeviceError`` (a ``GoniofrostError``); ``str(exc)`` reads
``AXIS: COMMAND: WHAT (reply: REPLY)``.
"""
from __future__ import annotations

from collections.abc import Sequence

from goniofrost.core.errors import GoniofrostError


def _show_reply(reply) -> str:
    """Render a reply for a message: bytes as spaced hex (as in the manuals), else repr."""
    if isinstance(reply, (bytes, bytearray)):
        return bytes(reply).hex(" ").upper() or "nothing"
    return repr(reply)


class DeviceError(GoniofrostError):
    """A device did not do what it was told.

    Attributes: ``axis`` (axis or device name), ``command`` (what was sent, readable),
    ``reply`` (what came back: bytes, a decoded value, or None for nothing), ``detail`` (text).
    """

    what = "device error"

    def __init__(self, axis: str, command: str, reply=None, detail: str = "") -> None:
        self.axis, self.command, self.reply, self.detail = str(axis), str(command), reply, detail
        text = f"{self.axis}: {self.command}: {detail or self.what}"
        if reply is not None:
            text += f" (reply: {_show_reply(reply)})"
        super().__init__(text)


class DeviceTimeout(DeviceError):
    """No (complete) reply within the reply timeout, after the bounded retries."""

    what = "no reply"


class ChecksumError(DeviceError):
    """A reply arrived but its CRC / checksum does not match its content."""

    what = "reply checksum mismatch"


class ProtocolError(DeviceError):
    """A malformed or unexpected reply (wrong header, id, length, echo or value)."""

    what = "malformed or unexpected reply"


class ExceptionReply(DeviceError):
    """The device understood the command and refused it.

    ``code`` is the device's own code: a Modbus exception code, an SMC100 TE letter or a
    Dynamixel status error byte; ``detail`` gives its meaning.
    """

    what = "command refused"

    def __init__(self, axis: str, command: str, reply=None, detail: str = "", code=None) -> None:
        self.code = code
        super().__init__(axis, command, reply, detail)


class NotHomedError(ExceptionReply):
    """The device refused a command because its axis is not referenced (homed) yet: an SMC100
    stage refuses moves until it is (TE letter H)."""


class DeviceFault(DeviceError):
    """A hardware error, alarm or stall reported by (or detected on) the device.

    ``causes`` is a list of readable causes, e.g. ``["overload", "overheating"]``.
    """

    what = "device fault"

    def __init__(self, axis: str, command: str, reply=None, causes: Sequence[str] = (),
                 detail: str = "") -> None:
        self.causes = list(causes)
        super().__init__(axis, command, reply,
                         detail or f"device fault: {', '.join(self.causes) or 'unknown cause'}")


class AxisLimitError(DeviceError):
    """A target outside the axis limits; nothing was sent to the device."""

    def __init__(self, axis: str, start: float, target: float, limits: Sequence[float],
                 units: str = "deg") -> None:
        self.start, self.target, self.limits, self.units = start, target, tuple(limits), units
        lo, hi = self.limits
        super().__init__(axis, f"move to {target:g} {units}", None,
                         f"target {target:g} {units} outside limits [{lo:g}, {hi:g}] {units} "
                         f"(axis at {start:g} {units}); nothing sent")


class ArrivalError(DeviceError):
    """A move ended (the device stopped) but not within tolerance of its target."""

    def __init__(self, axis: str, target: float, position: float, tolerance: float,
                 units: str = "deg") -> None:
        self.target, self.position, self.tolerance, self.units = target, position, tolerance, units
        super().__init__(axis, f"move to {target:g} {units}", position,
                         f"stopped at {position:.4f} {units}, not within {tolerance:g} {units} "
                         f"of the target {target:g} {units}")


class NotConnectedError(DeviceError):
    """A command on an axis or device that was not connected (connect() first) or was closed."""

    what = "not connected: call connect() first"
