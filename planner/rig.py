"""Rig files: the YAML description of a gonioreflectometer's geometry and axes, validated strictly.

A rig file has ``name``, ``simulated``, ``geometry``, ``axes`` and optionally ``lamp``, ``camera``,
``sim`` and ``alignment`` (the ALIGNMENT.json of ``goniofrost align``, relative to the rig file;
see ``config/rigs/template.yaml`` for every key, documented). This module owns the
geometry and the motion keys of each axis; the ``driver`` sections (of each axis and of the lamp),
``camera`` and ``sim`` belong to other packages and are checked by validators plugged in through
``section_validators`` (``goniofrost.capture.rig_file.load_checked_rig`` plugs in the real ones).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from goniofrost.core.cache import content_key
from goniofrost.core.errors import ConfigError

from . import schema as S
from .alignment import load_alignment

# validator(section, source, keypath) raises ConfigError on a bad section; it may return the
# section with its defaults filled in, which the Rig then keeps.
SectionValidator = Callable[[Mapping, str, str], None]


class Role(str, enum.Enum):
    """What an axis moves (DESIGN.md, "The default simulated rig")."""

    CAMERA_ARM = "camera_arm"    # camera direction C(alpha) = R_z(alpha) L
    SAMPLE_YAW = "sample_yaw"    # stage rotation psi about the world z axis
    SAMPLE_TILT = "sample_tilt"  # stage tilt tau about the yawed horizontal axis


# The joint order of every joint array: (camera_arm, sample_yaw, sample_tilt).
ROLE_ORDER = (Role.CAMERA_ARM, Role.SAMPLE_YAW, Role.SAMPLE_TILT)

_TOP_REQUIRED = ("name", "geometry", "axes")
_TOP_OPTIONAL = ("simulated", "lamp", "camera", "sim", "alignment", "lab")
_GEOMETRY_KEYS = ("light_direction", "min_arm_separation_deg", "tilt_limit_deg")
_AXIS_KEYS = ("role", "limits_deg", "speed_deg_s", "accel_deg_s2", "home_deg", "tolerance_deg", "driver")


@dataclass(frozen=True)
class Geometry:
    """Fixed geometry of the rig, world frame z up, sample at the origin.

    ``light_direction``: unit vector (3,) of the fixed lamp, horizontal (z = 0).
    ``min_arm_separation_deg``: the camera arm may not come closer to the light than this (degrees).
    ``tilt_limit_deg``: the stage tilt stays within +-this (degrees; mechanical/occlusion limit).
    """

    light_direction: tuple[float, float, float]
    min_arm_separation_deg: float
    tilt_limit_deg: float

    @property
    def light_azimuth_deg(self) -> float:
        """Azimuth of the light in the horizontal plane (degrees)."""
        return math.degrees(math.atan2(self.light_direction[1], self.light_direction[0]))


@dataclass(frozen=True)
class AxisSpec:
    """One motorised axis: limits, home and tolerance in degrees, speed in deg/s, accel in deg/s^2."""

    name: str
    role: Role
    limits_deg: tuple[float, float]
    speed_deg_s: float
    accel_deg_s2: float
    home_deg: float
    tolerance_deg: float
    driver: dict = field(compare=False)


@dataclass(frozen=True)
class Rig:
    """A validated rig file. ``axes`` maps axis name -> AxisSpec, one axis per Role."""

    name: str
    simulated: bool
    geometry: Geometry
    axes: dict
    lamp: dict
    camera: dict
    sim: dict
    source: str
    kinematic_hash: str
    raw: dict = field(compare=False, repr=False)
    # What the camera can measure (planner.view.Measurability; None: not checked) and the axes'
    # zero offsets (planner.alignment.Alignment; None: a perfectly built rig). Attached by
    # goniofrost.capture.rig_file.load_checked_rig from the camera section and the alignment file.
    view: Any = field(default=None, compare=False, repr=False)
    alignment: Any = None
    # the lab's metadata (lab, lens, lamp: checked by goniofrost.capture.lab), never kinematics
    lab: dict = field(default_factory=dict, compare=False)

    def axis(self, role: Role | str) -> AxisSpec:
        """The axis that plays ``role``."""
        role = Role(role)
        return next(a for a in self.axes.values() if a.role is role)

    @property
    def joint_names(self) -> tuple[str, str, str]:
        """Axis names in joint order (camera_arm, sample_yaw, sample_tilt roles)."""
        return tuple(self.axis(r).name for r in ROLE_ORDER)

    @property
    def ordered_axes(self) -> tuple[AxisSpec, AxisSpec, AxisSpec]:
        """Axis specs in joint order."""
        return tuple(self.axis(r) for r in ROLE_ORDER)

    @property
    def home(self) -> tuple[float, float, float]:
        """Home joints (degrees) in joint order."""
        return tuple(a.home_deg for a in self.ordered_axes)


def load_rig(path: str | Path, section_validators: Mapping[str, SectionValidator] | None = None) -> Rig:
    """Read and validate a rig file; raise ConfigError (file, key path, expected, found) on any fault.

    ``section_validators`` may hold ``"driver"`` (called for each axis's ``driver`` section and the
    lamp's), ``"camera"`` and ``"sim"``; a section without a validator is kept as given.
    """
    source = str(path)
    raw = S.read_yaml(path)
    return rig_from_mapping(raw, source, section_validators)


def rig_from_mapping(raw: Any, source: str,
                     section_validators: Mapping[str, SectionValidator] | None = None) -> Rig:
    """Validate an already parsed rig mapping (``source`` names it in errors)."""
    validators = dict(section_validators or {})
    top = S.mapping(raw, source, "")
    S.check_keys(top, source, "", _TOP_REQUIRED, _TOP_OPTIONAL)
    name = S.text(top["name"], source, "name")
    simulated = S.boolean(top.get("simulated", False), source, "simulated")
    geometry = _geometry(top["geometry"], source)
    axes = _axes(top["axes"], source, geometry, validators.get("driver"))
    lamp = _lamp(top.get("lamp", {}), source, validators.get("driver"))
    camera = _plugged(top, "camera", source, validators.get("camera"))
    sim = _plugged(top, "sim", source, validators.get("sim"))
    lab = _plugged(top, "lab", source, validators.get("lab"))
    alignment = None
    if "alignment" in top:
        written = Path(S.text(top["alignment"], source, "alignment"))
        joint_order = [next(a.name for a in axes.values() if a.role is role) for role in ROLE_ORDER]
        alignment = load_alignment(written if written.is_absolute() else Path(source).parent / written, joint_order)
    return Rig(name=name, simulated=simulated, geometry=geometry, axes=axes, lamp=lamp,
               camera=camera, sim=sim, source=source,
               kinematic_hash=kinematic_hash(geometry, axes), raw=dict(top), alignment=alignment, lab=lab)


def kinematic_hash(geometry: Geometry, axes: Mapping[str, AxisSpec]) -> str:
    """Hash of everything that changes poses or move times (not driver endpoints); 16 hex digits."""
    motion = sorted(
        (a.name, a.role.value, a.limits_deg, a.speed_deg_s, a.accel_deg_s2, a.home_deg, a.tolerance_deg)
        for a in axes.values())
    geo = (geometry.light_direction, geometry.min_arm_separation_deg, geometry.tilt_limit_deg)
    return content_key("rig-kinematics-v1", geo, motion)[:16]


def _geometry(value: Any, source: str) -> Geometry:
    geo = S.mapping(value, source, "geometry")
    S.check_keys(geo, source, "geometry", _GEOMETRY_KEYS)
    light = S.numbers(geo["light_direction"], source, "geometry.light_direction", 3)
    norm = math.sqrt(sum(c * c for c in light))
    if abs(norm - 1.0) > 1e-6 or abs(light[2]) > 1e-9:
        # The camera arm turns about the world z axis in the light's horizontal plane.
        raise ConfigError(source, "geometry.light_direction", "a horizontal unit vector [x, y, 0]", list(light))
    return Geometry(
        light_direction=tuple(c / norm for c in light),
        min_arm_separation_deg=S.number(geo["min_arm_separation_deg"], source,
                                        "geometry.min_arm_separation_deg", low=0.0, high=180.0, high_open=True),
        tilt_limit_deg=S.number(geo["tilt_limit_deg"], source, "geometry.tilt_limit_deg",
                                low=0.0, high=90.0, low_open=True, high_open=True),
    )


def _axes(value: Any, source: str, geometry: Geometry, driver_check: SectionValidator | None) -> dict:
    axes_map = S.mapping(value, source, "axes")
    axes = {name: _axis(name, spec, source, driver_check) for name, spec in axes_map.items()}
    for role in ROLE_ORDER:
        names = [a.name for a in axes.values() if a.role is role]
        if len(names) != 1:
            raise ConfigError(source, "axes", f"exactly one axis with role {role.value}",
                              f"{len(names)} ({', '.join(names) or 'none'})")
    tilt = next(a for a in axes.values() if a.role is Role.SAMPLE_TILT)
    if abs(tilt.home_deg) > geometry.tilt_limit_deg:
        raise ConfigError(source, f"axes.{tilt.name}.home_deg",
                          f"a tilt within the stage limit +-{geometry.tilt_limit_deg:g}", tilt.home_deg)
    return axes


def _axis(name: str, value: Any, source: str, driver_check: SectionValidator | None) -> AxisSpec:
    kp = f"axes.{name}"
    spec = S.mapping(value, source, kp)
    S.check_keys(spec, source, kp, _AXIS_KEYS)
    role = Role(S.choice(spec["role"], source, f"{kp}.role", [r.value for r in Role]))
    lo, hi = S.numbers(spec["limits_deg"], source, f"{kp}.limits_deg", 2)
    if not lo < hi:
        raise ConfigError(source, f"{kp}.limits_deg", "[low, high] with low < high", [lo, hi])
    home = S.number(spec["home_deg"], source, f"{kp}.home_deg", low=lo, high=hi)
    driver = _checked(S.mapping(spec["driver"], source, f"{kp}.driver"), source, f"{kp}.driver", driver_check)
    return AxisSpec(
        name=name, role=role, limits_deg=(lo, hi), home_deg=home, driver=driver,
        speed_deg_s=S.number(spec["speed_deg_s"], source, f"{kp}.speed_deg_s", low=0.0, low_open=True),
        accel_deg_s2=S.number(spec["accel_deg_s2"], source, f"{kp}.accel_deg_s2", low=0.0, low_open=True),
        tolerance_deg=S.number(spec["tolerance_deg"], source, f"{kp}.tolerance_deg", low=0.0, low_open=True),
    )


def _lamp(value: Any, source: str, driver_check: SectionValidator | None) -> dict:
    lamp = S.mapping(value, source, "lamp")
    S.check_keys(lamp, source, "lamp", (), ("driver", "beam_diameter_mm"))
    out = dict(lamp)
    if "beam_diameter_mm" in lamp:
        # the collimated beam, centred on the rotation centre: the patch must lie inside it
        out["beam_diameter_mm"] = S.number(lamp["beam_diameter_mm"], source, "lamp.beam_diameter_mm",
                                           low=0.0, low_open=True)
    if "driver" in lamp:
        out["driver"] = _checked(S.mapping(lamp["driver"], source, "lamp.driver"), source, "lamp.driver", driver_check)
    return out


def _plugged(top: Mapping, key: str, source: str, check: SectionValidator | None) -> dict:
    if key not in top:
        return {}
    return _checked(S.mapping(top[key], source, key), source, key, check)


def _checked(section: Mapping, source: str, keypath: str, check: SectionValidator | None) -> dict:
    """A plain-dict copy of a section after its validator ran (a validator may return it completed)."""
    if check is None:
        return dict(section)
    completed = check(section, source, keypath)
    return dict(completed) if isinstance(completed, Mapping) else dict(section)
