"""Build every Axis (and the Lamp) of a rig from its driver sections, and handle them as one.

``RigDevices.from_sections(...)`` only constructs (nothing is opened); ``connect_all()`` connects
and enables every axis; ``close_all()`` releases every connection. Stopping is not done here: the
one stop path for all axes (command each to stop, then confirm each at rest) is the engine's
``goniofrost.capture.executor.stop_axes``, which the rig wiring calls before ``close_all``.
"""
from __future__ import annotations

import importlib
import logging
from collections.abc import Mapping

from .axis import Axis, AxisConfig

log = logging.getLogger(__name__)

# protocol -> (module, class); each class has ``from_section(config: AxisConfig, section)``.
AXIS_CLASSES = {
    "dynamixel": ("drivers.dynamixel", "DynamixelAxis"),
    "modbus-tcp": ("drivers.modbus_drive", "ModbusAxis"),
    "modbus-rtu": ("drivers.modbus_drive", "ModbusAxis"),
    "smc100": ("drivers.smc100", "SMC100Axis"),
}


def _get(spec, key, default=None):
    return spec.get(key, default) if isinstance(spec, Mapping) else getattr(spec, key, default)


def axis_from_spec(name: str, spec) -> Axis:
    """One Axis (not connected) from a rig-file axis entry (mapping or planner AxisSpec)."""
    section = dict(_get(spec, "driver"))
    module_name, class_name = AXIS_CLASSES[section["protocol"]]
    cls = getattr(importlib.import_module(module_name), class_name)
    config = AxisConfig.from_spec(name, spec, retries=section.get("retries"))
    return cls.from_section(config, section)


class RigDevices:
    """The axes (name -> Axis) and the lamp (or None) of one rig."""

    def __init__(self, axes: dict[str, Axis], lamp=None) -> None:
        self.axes, self.lamp = axes, lamp
        self._connected: list = []

    @classmethod
    def from_sections(cls, axes_specs, lamp_section: Mapping | None = None) -> "RigDevices":
        """Build from ``axes_specs`` (name -> axis entry with its ``driver`` section) and the lamp's
        driver section. Also accepts a planner Rig, or ``{"axes": ..., "lamp": ...}`` as returned by
        ``sim.rig.SimulatedRig.resolved_driver_sections()``."""
        if hasattr(axes_specs, "axes"):  # a planner Rig
            lamp_section = (axes_specs.lamp or {}).get("driver")
            axes_specs = axes_specs.axes
        elif isinstance(axes_specs, Mapping) and set(axes_specs) <= {"axes", "lamp"} and "axes" in axes_specs:
            axes_specs, lamp_section = axes_specs["axes"], axes_specs.get("lamp")
        axes = {name: axis_from_spec(name, spec) for name, spec in axes_specs.items()}
        lamp = None
        if lamp_section:
            from .lamp import Lamp  # only rigs with a lamp need the Modbus client
            lamp = Lamp.from_section(lamp_section, axes)  # ``device``: share that axis's link
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
