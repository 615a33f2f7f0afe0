"""The typed rig spec every layer reads a rig through: frozen dataclasses.

``planner.rig`` builds it from a checked rig file, ``drivers.rig_devices`` and ``sim.rig`` build
devices from it; ``RigSpec.with_drivers`` fills in the endpoints a simulated rig opened.
"""
from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from dataclasses import dataclass, field


class Role(str, enum.Enum):
    """What an axis moves (DESIGN.md, "The default simulated rig")."""

    CAMERA_ARM = "camera_arm"    # camera direction C(alpha) = R_z(alpha) L
    SAMPLE_YAW = "sample_yaw"    # stage rotation psi about the world z axis
    SAMPLE_TILT = "sample_tilt"  # stage tilt tau about the yawed horizontal axis


# The joint order of every joint array: (camera_arm, sample_yaw, sample_tilt).
ROLE_ORDER = (Role.CAMERA_ARM, Role.SAMPLE_YAW, Role.SAMPLE_TILT)


@dataclass(frozen=True)
class AxisSpec:
    """One motorised axis: limits, home and tolerance in degrees, speed in deg/s, accel in deg/s^2;
    ``driver`` is its checked driver section (``drivers.config``)."""

    name: str
    role: Role
    limits_deg: tuple[float, float]
    speed_deg_s: float
    accel_deg_s2: float
    home_deg: float
    tolerance_deg: float
    driver: Mapping = field(compare=False)


@dataclass(frozen=True)
class RigSpec:
    """What the devices of a rig are built from: ``axes`` (name -> AxisSpec), ``lamp`` (the lamp
    section: ``driver``, ``beam_diameter_mm``), ``sim`` (the checked sim section) and ``source``
    (the file that named them, for errors)."""

    axes: Mapping[str, AxisSpec]
    lamp: Mapping
    sim: Mapping
    source: str

    @property
    def lamp_driver(self) -> Mapping | None:
        """The lamp's driver section, or None for a rig without a driven lamp."""
        return (self.lamp or {}).get("driver") or None

    def with_drivers(self, drivers: Mapping[str, Mapping], lamp_driver: Mapping | None = None):
        """The same spec (same class) with these axes' driver sections (name -> section) and,
        when given, the lamp's driver section replaced."""
        axes = {name: dataclasses.replace(axis, driver=dict(drivers[name])) if name in drivers else axis
                for name, axis in self.axes.items()}
        lamp = dict(self.lamp or {})
        if lamp_driver is not None:
            lamp["driver"] = dict(lamp_driver)
        return dataclasses.replace(self, axes=axes, lamp=lamp)
