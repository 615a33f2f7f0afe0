"""Load a rig file with every section checked by the package that owns it.

``planner.rig`` checks the geometry and the axes' motion keys; the ``driver`` sections are checked
by ``drivers.config.validate_driver_section``, the ``camera`` section by ``calib.config`` and the
``sim`` section by ``sim.config``. Each validator is imported when a rig is loaded; one that is
named here but cannot be found is an ImportError, never a section left unchecked.

The loaded rig carries what the camera can measure (``planner.view.Measurability``, from the
camera model and the holder card of ``calib.holder``) and its alignment (the rig file's
``alignment`` key, or the ``--alignment`` file that overrides it).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable, Mapping

import dataclasses

from planner.alignment_file import load_alignment
from planner.rig import Rig
from planner.rig import load_rig as _load_rig
from planner.view import Measurability

# lamp.max_incidence_deg when the rig file does not say: the light's irradiance on the patch is
# cos theta_i of the normal's, 1/57 at 89 deg; the MERL grid's most grazing cells (89.97 deg,
# 1/1900) left a capture's sample below its SNR minimum at 16 s, which ends the session.
DEFAULT_MAX_INCIDENCE_DEG = 89.0

# section -> (module, function) of its validator: validator(section, source, keypath) -> None.
VALIDATORS: dict[str, tuple[str, str]] = {
    "driver": ("drivers.config", "validate_driver_section"),
    "camera": ("calib.config", "validate_camera_section"),
    "sim": ("sim.config", "validate_sim_section"),
    "twins": ("sim.config", "validate_twins_section"),
    "lab": ("goniofrost.rig.lab", "validate_lab_section"),
    "suspenders": ("goniofrost.rig.suspenders", "validate_suspenders_section"),
    "pause": ("goniofrost.rig.pause", "validate_pause_section"),
}
# checks of the loaded rig that need several sections: check(rig) -> None, raises ConfigError.
RIG_CHECKS: tuple[tuple[str, str], ...] = (
    ("sim.config", "check_sim_against_rig"),  # every fault drill and misalignment names an axis of the rig
    ("drivers.config", "check_lamp_against_rig"),  # a lamp on an axis sits on a Modbus axis
    ("goniofrost.rig.suspenders", "check_suspenders_against_rig"),  # the interlock sits on a Modbus axis
)


def _function(module_name: str, func_name: str, what: str) -> Callable:
    """``module_name.func_name``; ImportError naming ``what`` cannot be checked when it is missing."""
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise ImportError(f"{what} cannot be checked: its validator {module_name}.{func_name} is missing "
                          f"({exc})") from exc
    func = getattr(module, func_name, None)
    if not callable(func):
        raise ImportError(f"{what} cannot be checked: module {module_name} has no function {func_name}")
    return func


def section_validators() -> dict[str, Callable[[Mapping, str, str], None]]:
    """Every validator of VALIDATORS, by section name; ImportError when one does not exist."""
    return {section: _function(module_name, func_name, f"the rig file's {section!r} sections")
            for section, (module_name, func_name) in VALIDATORS.items()}


def load_checked_rig(path: str | Path, alignment: str | Path | None = None) -> Rig:
    """Read and fully validate a rig file (raises goniofrost.core.errors.ConfigError); attach its
    measurability and its alignment (``alignment``: an ALIGNMENT.json overriding the rig file's)."""
    rig = _load_rig(path, section_validators())
    for module_name, func_name in RIG_CHECKS:
        _function(module_name, func_name, "the rig file")(rig)
    if alignment is not None:
        rig = dataclasses.replace(rig, alignment=load_alignment(alignment, list(rig.joint_names), rig.name))
    return dataclasses.replace(rig, view=measurability(rig))


def measurability(rig: Rig) -> Measurability | None:
    """What the rig's camera can measure (None without a camera model)."""
    from calib.holder import DEFAULT_LAYOUT
    from goniofrost.core.camera_model import CameraModel

    camera = rig.camera or {}
    if "intrinsics" not in camera or "mount" not in camera:
        return None
    beam = rig.lamp.get("beam_diameter_mm")
    incidence = rig.lamp.get("max_incidence_deg", DEFAULT_MAX_INCIDENCE_DEG)
    return Measurability(camera=CameraModel.from_section(camera),
                         roi_mm=tuple(map(tuple, DEFAULT_LAYOUT.patch_polygon(camera["roi_margin"]))),
                         patch_mm=tuple(map(tuple, DEFAULT_LAYOUT.patch_polygon(0.0))),
                         min_pixels=int(camera["min_roi_pixels"]),
                         beam_radius_mm=None if beam is None else beam / 2.0, max_incidence_deg=incidence)


def command_steps(rig) -> list[float]:
    """Degrees between the positions each axis of ``rig`` (``joint_names`` order) can be commanded
    to, from its driver section (``drivers.config.command_step_deg``): what ``plan`` puts the joint
    targets on (``planner.steps``)."""
    from drivers.config import command_step_deg

    return [command_step_deg(rig.axes[name].driver) for name in rig.joint_names]
