"""Build every Axis (and the Lamp) of a rig from its driver sections, and handle them as one.

``RigDevices.from_rig(rig)`` constructs; ``connect_all()`` opens each connection
(``open_transport``) and enables the axes; ``reconnect(name)`` opens one again;
``close_all()`` releases them. Stopping is
``goniofrost.rig.stop.stop_axes``.
"""
from __future__ import annotations

import importlib
import logging

from goniofrost.core.rig_spec import AxisSpec, RigSpec

from .axis import Axis, AxisConfig
from .transport import open_serial, open_tcp

log = logging.getLogger(__name__)

# protocol -> (default baud, default parity, XON/XOFF, default reply timeout in ms) of its serial line
SERIAL_LINES = {
    "smc100": (57600, "N", True, 200.0),     # the SMC100 manual: 57600 8N1, XON/XOFF
    "dynamixel": (57600, "N", False, None),  # the SDK polls (drivers.dynamixel._Port)
    "modbus-rtu": (115200, "E", False, 300.0),  # Modbus over serial line: even parity by default
}
TCP_REPLY_TIMEOUT_MS = 300.0

# protocol -> (module, class); each class has ``from_section(config: AxisConfig, section)``.
AXIS_CLASSES = {
    "dynamixel": ("drivers.dynamixel", "DynamixelAxis"),
    "modbus-tcp": ("drivers.modbus_drive", "ModbusAxis"),
    "modbus-rtu": ("drivers.modbus_drive", "ModbusAxis"),
    "smc100": ("drivers.smc100", "SMC100Axis"),
}

# camera kind -> (module, class): the class declares KEYS, the keys of the rig file's camera:
# section only its kind reads (a goniofrost.core.config_check Key table), and builds itself with
# ``from_section(section, source, ask, image_source=None, device_class=None)`` (not connected).
CAMERA_CLASSES = {
    "rawfile": ("drivers.tethered", "TetheredCamera"),
    "pylon": ("drivers.pylon", "PylonCamera"),
}
# The simulated camera (goniofrost.rig.simulated builds it) keeps these keys of the folder camera:
# shutter_speeds move its ladder, and `goniofrost sim --write-rig` turns it into a folder camera.
SIM_CAMERA = "sim"
SIM_CAMERA_KEYS = ("shutter_speeds", "exposure_tolerance")


def camera_class(kind: str):
    """The camera class of a registered ``kind`` (CAMERA_CLASSES), imported on first use."""
    module_name, class_name = CAMERA_CLASSES[kind]
    return getattr(importlib.import_module(module_name), class_name)


def open_transport(name: str, section: Mapping):
    """Open the serial port or TCP connection of one validated driver section (an axis's or the
    lamp's own); DeviceError naming ``name`` when it cannot be opened."""
    protocol = section["protocol"]
    if protocol == "modbus-tcp":
        timeout_ms = section.get("reply_timeout_ms", TCP_REPLY_TIMEOUT_MS)
        return open_tcp(name, section.get("host", "127.0.0.1"), section["port"], timeout_ms / 1000.0)
    baud, parity, xonxoff, timeout_ms = SERIAL_LINES[protocol]
    timeout_ms = section.get("reply_timeout_ms", timeout_ms) if timeout_ms is not None else 1.0
    return open_serial(name, section["port"], section.get("baud", baud), timeout_ms / 1000.0,
                       parity=section.get("parity", parity), xonxoff=xonxoff)


def connect_axis(axis: Axis, section: Mapping) -> None:
    """Open the connection of ``section`` and connect ``axis`` on it (which then owns it)."""
    transport = open_transport(axis.name, section)
    axis.connect(transport)  # closes the transport itself when the handshake fails


def axis_from_spec(spec: AxisSpec, **overrides) -> Axis:
    """One Axis (not connected) of a rig's typed axis spec; ``overrides`` replace AxisConfig fields."""
    module_name, class_name = AXIS_CLASSES[spec.driver["protocol"]]
    cls = getattr(importlib.import_module(module_name), class_name)
    return cls.from_section(AxisConfig.from_spec(spec, **overrides), dict(spec.driver))


class RigDevices:
    """The axes (name -> Axis) and the lamp (or None) of one rig."""

    def __init__(self, axes: dict[str, Axis], lamp=None, sections: Mapping | None = None) -> None:
        self.axes, self.lamp = axes, lamp
        self.sections = dict(sections or {})  # name (and "lamp") -> driver section: what to open
        self._connected: list = []

    @classmethod
    def from_rig(cls, rig: RigSpec) -> "RigDevices":
        """Build from a typed rig spec (a checked ``planner.rig.Rig``, or the spec a simulated rig
        hands back with its endpoints, ``sim.rig.SimulatedRig.resolved_rig()``)."""
        axes = {name: axis_from_spec(spec) for name, spec in rig.axes.items()}
        sections = {name: dict(spec.driver) for name, spec in rig.axes.items()}
        lamp = None
        if rig.lamp_driver:
            from .lamp import Lamp  # only rigs with a lamp need the Modbus client
            lamp = Lamp.from_section(rig.lamp_driver, axes)  # ``device``: share that axis's link
            sections["lamp"] = dict(rig.lamp_driver)
        return cls(axes, lamp, sections)

    def connect_all(self, enable: bool = True) -> None:
        """Open every device's connection and connect (and enable) every axis, then the lamp; on
        failure close what was opened, re-raise."""
        try:
            for name, axis in self.axes.items():
                connect_axis(axis, self.sections[name])
                self._connected.append(axis)
                if enable:
                    axis.enable()
            if self.lamp is not None:
                section = self.sections.get("lamp", {})
                own = "device" not in section  # else it shares its axis's connection
                self.lamp.connect(open_transport("lamp", section) if own else None)
                self._connected.append(self.lamp)
        except BaseException:
            self.close_all()
            raise

    def reconnect(self, name: str) -> None:
        """Close and open again the connection of axis ``name`` (or ``"lamp"``), then check it answers
        (an axis is enabled again, as ``connect_all`` does; nothing moves). A lamp on an axis's
        link only checks that link, which its axis reopens. DeviceError when it does not answer."""
        if name == "lamp":
            section = self.sections.get("lamp", {})
            own = "device" not in section
            if own:
                self.lamp.close()
            self.lamp.connect(open_transport("lamp", section) if own else None)
            return
        axis = self.axes[name]
        axis.close()
        connect_axis(axis, self.sections[name])
        axis.enable()

    def close_all(self) -> None:
        """Close every connection that was opened (lamp first); logs failures, never raises."""
        for device in reversed(self._connected):
            try:
                device.close()
            except Exception as exc:  # noqa: BLE001 - release everything else anyway
                log.warning("close %s failed: %s", getattr(device, "name", device), exc)
        self._connected.clear()

    def __enter__(self) -> "RigDevices":
        self.connect_all()
        return self

    def __exit__(self, *exc) -> None:
        self.close_all()  # the caller stops the axes first, through stop_axes (module doc)
