"""Rig files: the YAML description of a gonioreflectometer's geometry and axes, validated strictly.

Entry point ``load_rig``. This module checks the geometry and each axis's motion keys; the
``driver``, ``camera`` and ``sim`` sections are checked by validators passed as
``section_validators``. Every key: ``config/rigs/template.yaml``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from goniofrost.core.cache import content_key
from goniofrost.core.config_check import (ABSENT, Key, check_section, is_bool, is_mapping, is_text, number_in,
                                          numbers, one_of)
from goniofrost.core.errors import ConfigError
from goniofrost.core.rig_spec import ROLE_ORDER, AxisSpec, RigSpec, Role

from . import schema as S
from .alignment_file import load_alignment

__all__ = ["ROLE_ORDER", "AxisSpec", "Geometry", "Rig", "Role", "load_rig", "rig_from_mapping", "kinematic_hash"]

# validator(section, source, keypath) raises ConfigError on a bad section; it may return the
# section with its defaults filled in, which the Rig then keeps.
SectionValidator = Callable[[Mapping, str, str], None]

_POSITIVE = number_in(0.0, low_open=True)
_TOP_KEYS = {
    "name": Key(is_text, "a non-empty text"),
    "simulated": Key(is_bool, "true or false", False),
    "geometry": Key(is_mapping, "a mapping"),
    "axes": Key(is_mapping, "a mapping"),
    "lamp": Key(is_mapping, "a mapping", {}),
    "camera": Key(is_mapping, "a mapping", ABSENT),
    "sim": Key(is_mapping, "a mapping", ABSENT),
    "alignment": Key(is_text, "a non-empty text (the ALIGNMENT.json of goniofrost align)", ABSENT),
    "lab": Key(is_mapping, "a mapping", ABSENT),  # the lab's metadata (goniofrost.rig.lab checks it)
    "twins": Key(is_mapping, "a mapping", ABSENT),  # running twins behind a real rig file (sim.config checks it)
    "suspenders": Key(is_mapping, "a mapping", ABSENT),  # goniofrost.rig.suspenders checks it
    "pause": Key(is_mapping, "a mapping", ABSENT),  # what a paused capture holds (goniofrost.rig.pause checks it)
}
_GEOMETRY_KEYS = {
    "light_direction": Key(numbers(3), "a list of 3 numbers"),
    "min_arm_separation_deg": number_in(0.0, 180.0, high_open=True),
    "tilt_limit_deg": number_in(0.0, 90.0, low_open=True, high_open=True),
}
_AXIS_KEYS = {
    "role": Key(one_of(*(r.value for r in Role)), f"one of {', '.join(r.value for r in Role)}"),
    "limits_deg": Key(numbers(2), "a list of 2 numbers"),
    "speed_deg_s": _POSITIVE,
    "accel_deg_s2": _POSITIVE,
    "home_deg": number_in(),
    "tolerance_deg": _POSITIVE,
    "driver": Key(is_mapping, "a mapping"),
}
_LAMP_KEYS = {
    "driver": Key(is_mapping, "a mapping", ABSENT),
    # the collimated beam, centred on the rotation centre: the patch must lie inside it
    "beam_diameter_mm": dataclasses.replace(_POSITIVE, default=ABSENT),
    # the light's largest angle from the sample's normal that still lights the patch enough to
    # measure (its irradiance falls as cos theta_i: 1/57 of the normal's at 89 deg)
    "max_incidence_deg": dataclasses.replace(number_in(0.0, 90.0, low_open=True), default=ABSENT),
}


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
class Rig(RigSpec):
    """A validated rig file: the typed ``RigSpec`` (``axes`` maps axis name -> AxisSpec, one axis
    per Role; ``lamp``, ``sim``, ``source``) with its geometry and camera section."""

    name: str
    simulated: bool
    geometry: Geometry
    camera: dict
    kinematic_hash: str
    raw: dict = field(compare=False, repr=False)
    # What the camera can measure (planner.view.Measurability; None: not checked) and the axes'
    # zero offsets (planner.alignment.Alignment; None: a perfectly built rig). Attached by
    # goniofrost.rig.file.load_checked_rig from the camera section and the alignment file.
    view: Any = field(default=None, compare=False, repr=False)
    alignment: Any = None
    # the lab's metadata (lab, lens, lamp: checked by goniofrost.rig.lab), never kinematics
    lab: dict = field(default_factory=dict, compare=False)
    # the running twins a rig file of `goniofrost sim --write-rig` points at (clock_speedup,
    # camera_service_port; checked by sim.config); empty for every other rig
    twins: dict = field(default_factory=dict, compare=False)
    # what pauses a capture until it clears (checked by goniofrost.rig.suspenders); {}: nothing
    suspenders: dict = field(default_factory=dict, compare=False)
    # what a paused capture holds (checked by goniofrost.rig.pause); {}: the defaults
    pause: dict = field(default_factory=dict, compare=False)

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
    S.check_filled_in(raw, source)
    return rig_from_mapping(raw, source, section_validators)


def rig_from_mapping(raw: Any, source: str,
                     section_validators: Mapping[str, SectionValidator] | None = None) -> Rig:
    """Validate an already parsed rig mapping (``source`` names it in errors)."""
    validators = dict(section_validators or {})
    top = check_section(raw, _TOP_KEYS, source, "")
    geometry = _geometry(top["geometry"], source)
    axes = _axes(top["axes"], source, geometry, validators.get("driver"))
    lamp = check_section(top["lamp"], _LAMP_KEYS, source, "lamp")
    for key in ("beam_diameter_mm", "max_incidence_deg"):
        if key in lamp:
            lamp[key] = float(lamp[key])
    if "driver" in lamp:
        lamp["driver"] = _checked(lamp["driver"], source, "lamp.driver", validators.get("driver"))
    owned = ("camera", "sim", "lab", "twins", "suspenders", "pause")  # the sections other packages own
    camera, sim, lab, twins, suspenders, pause = (_checked(top[key], source, key, validators.get(key)) if key in top else {}
                                           for key in owned)
    alignment = None
    if "alignment" in top:
        written = Path(top["alignment"])
        joint_order = [next(a.name for a in axes.values() if a.role is role) for role in ROLE_ORDER]
        alignment = load_alignment(written if written.is_absolute() else Path(source).parent / written, joint_order,
                                   top["name"])
    return Rig(name=top["name"], simulated=top["simulated"], geometry=geometry, axes=axes, lamp=lamp,
               camera=camera, sim=sim, source=source,
               kinematic_hash=kinematic_hash(geometry, axes), raw=dict(raw), alignment=alignment, lab=lab,
               twins=twins, suspenders=suspenders, pause=pause)


def kinematic_hash(geometry: Geometry, axes: Mapping[str, AxisSpec]) -> str:
    """Hash of everything that changes poses or move times (not driver endpoints); 16 hex digits."""
    motion = sorted(
        (a.name, a.role.value, a.limits_deg, a.speed_deg_s, a.accel_deg_s2, a.home_deg, a.tolerance_deg)
        for a in axes.values())
    geo = (geometry.light_direction, geometry.min_arm_separation_deg, geometry.tilt_limit_deg)
    return content_key("rig-kinematics-v1", geo, motion)[:16]


def _geometry(value: Any, source: str) -> Geometry:
    geo = check_section(value, _GEOMETRY_KEYS, source, "geometry")
    light = tuple(float(c) for c in geo["light_direction"])
    norm = math.sqrt(sum(c * c for c in light))
    if abs(norm - 1.0) > 1e-6 or abs(light[2]) > 1e-9:
        # The camera arm turns about the world z axis in the light's horizontal plane.
        raise ConfigError(source, "geometry.light_direction", "a horizontal unit vector [x, y, 0]", list(light))
    return Geometry(light_direction=tuple(c / norm for c in light),
                    min_arm_separation_deg=float(geo["min_arm_separation_deg"]),
                    tilt_limit_deg=float(geo["tilt_limit_deg"]))


def _axes(value: Any, source: str, geometry: Geometry, driver_check: SectionValidator | None) -> dict:
    axes_map = check_section(value, {}, source, "axes", open_keys=True)
    axes = {name: _axis(name, spec, source, driver_check) for name, spec in axes_map.items()}
    check_roles(axes, geometry, source)
    return axes


def check_roles(axes: Mapping[str, "AxisSpec"], geometry: Geometry, source: str) -> None:
    """Exactly one axis per role, and the tilt axis homes within the stage's tilt limit."""
    for role in ROLE_ORDER:
        names = [a.name for a in axes.values() if a.role is role]
        if len(names) != 1:
            raise ConfigError(source, "axes", f"exactly one axis with role {role.value}",
                              f"{len(names)} ({', '.join(names) or 'none'})")
    tilt = next(a for a in axes.values() if a.role is Role.SAMPLE_TILT)
    if abs(tilt.home_deg) > geometry.tilt_limit_deg:
        raise ConfigError(source, f"axes.{tilt.name}.home_deg",
                          f"a tilt within the stage limit +-{geometry.tilt_limit_deg:g}", tilt.home_deg)


def _axis(name: str, value: Any, source: str, driver_check: SectionValidator | None) -> AxisSpec:
    kp = f"axes.{name}"
    spec = check_section(value, _AXIS_KEYS, source, kp)
    lo, hi = (float(v) for v in spec["limits_deg"])
    if not lo < hi:
        raise ConfigError(source, f"{kp}.limits_deg", "[low, high] with low < high", [lo, hi])
    home = float(spec["home_deg"])
    if not lo <= home <= hi:
        raise ConfigError(source, f"{kp}.home_deg", f"a number in [{lo:g}, {hi:g}]", spec["home_deg"])
    return AxisSpec(name=name, role=Role(spec["role"]), limits_deg=(lo, hi), home_deg=home,
                    driver=_checked(spec["driver"], source, f"{kp}.driver", driver_check),
                    speed_deg_s=float(spec["speed_deg_s"]), accel_deg_s2=float(spec["accel_deg_s2"]),
                    tolerance_deg=float(spec["tolerance_deg"]))


def _checked(section: Mapping, source: str, keypath: str, check: SectionValidator | None) -> dict:
    """A plain-dict copy of a section after its validator ran (a validator may return it completed)."""
    if not isinstance(section, Mapping):
        raise ConfigError(source, keypath, "a mapping", section)
    if check is None:
        return dict(section)
    completed = check(section, source, keypath)
    return dict(completed) if isinstance(completed, Mapping) else dict(section)


# Each part of a rig file checked on its own (``goniofrost rig check`` reports every problem in one run).
TOP_KEYS, LAMP_KEYS = _TOP_KEYS, _LAMP_KEYS
geometry_from_mapping = _geometry
axis_from_mapping = _axis
