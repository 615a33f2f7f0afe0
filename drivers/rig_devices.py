"""Build every Axis (and the Lamp) of a rig from its driver sections, and handle them as one.

``RigDevices.from_rig(rig)`` only constructs (nothing is opened); ``connect_all()`` connects
and enables every axis; ``close_all()`` releases every connection. Stopping is not done here: the
one stop path for all axes (command each to stop, then confirm each at rest) is the engine's
``goniofrost.capture.executor.stop_axes``, which the rig wiring calls before ``close_all``.
"""
from __future__ import annotations

import importlib
import logging

from goniofrost.core.rig_spec import AxisSpec, RigSpec

from .axis import Axis, AxisConfig

log = logging.getLogger(__name__)

# protocol -> (module, class); each class has ``from_section(config: AxisConfig, section)``.
AXIS_CLASSES = {
    "dynamixel": ("drivers.dynamixel", "DynamixelAxis"),
    "modbus-tcp": ("drivers.modbus_drive", "ModbusAxis"),
    "modbus-rtu": ("drivers.modbus_drive", "ModbusAxis"),
    "smc100": ("drivers.smc100", "SMC100Axis"),
}


def axis_from_spec(spec: AxisSpec, **overrides) -> Axis:
    """One Axis (not connected) of a rig's typed axis spec; ``overrides`` replace AxisConfig fields."""
    module_name, class_name = AXIS_CLASSES[spec.driver["protocol"]]
    cls = getattr(importlib.import_module(module_name), class_name)
    return cls.from_section(AxisConfig.from_spec(spec, **overrides), dict(spec.driver))


class RigDevices:
    """The axes (name -> Axis) and the lamp (or None) of one rig."""

    def __init__(self, axes: dict[str, Axis], lamp=None) -> None:
        self.axes, self.lamp = axes, lamp
        self._connected: list = []

    @classmethod
    def from_rig(cls, rig: RigSpec) -> "RigDevices":
        """Build from a typed rig spec (a checked ``planner.rig.Rig``, or the spec a simulated rig
        hands back with its endpoints, ``sim.rig.SimulatedRig.resolved_rig()``)."""
        axes = {name: axis_from_spec(spec) for name, spec in rig.axes.items()}
        lamp = None
        if rig.lamp_driver:
            from .lamp import Lamp  # only rigs with a lamp need the Modbus client
            lamp = Lamp.from_section(rig.lamp_driver, axes)  # ``device``: share that axis's link
        return cls(axes, lamp)

    def connect_all(self, enable: bool = True) -> None:
        """Connect (and enable) every axis, then the lamp; on failure close what was opened, re-raise."""
        try:
            for axis in self.axes.values():
                axis.connect()
                self._connected.append(axis)
                if enable:
                    axis.enable()
            if self.lamp is not None:
                self.lamp.connect()
                self._connected.append(self.lamp)
        except BaseException:
            self.close_all()
            raise

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
