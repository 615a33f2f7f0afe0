"""The rig file's ``sim:`` section: every key the simulated rig reads, declared as data and checked.

``validate_sim_section`` (plugged into the rig loader) returns the section with its defaults
filled in, or raises one ``ConfigError``; ``check_sim_against_rig`` checks that faults and
misalignments name the rig's axes. Every key (``SIM_KEYS``): docs/reference/config-keys.md.
"""
from __future__ import annotations

from goniofrost.core.config_check import (ABSENT, Key, check_items, check_section, is_list, is_mapping,
                                          is_natural, is_number, is_text, one_of)
from goniofrost.core.errors import ConfigError

from .faults import SIM_FAULT_KINDS
from .misalignment import check_axes, check_values


def _camera(section, source: str, keypath: str) -> dict:
    from .camera import validate_sim_camera_section  # the camera owns its keys (imported on use)
    return validate_sim_camera_section(dict(section), source, keypath)


_LAMP_KEYS = {
    "drift_per_hour": Key(lambda v: is_number(v) and -1.0 <= v <= 1.0,
                          "a number in [-1, 1] (relative intensity change per simulated hour)", 0.02),
}
_FAULT_KEYS = {
    "axis": Key(is_text, "the name of an axis of this rig", ABSENT),  # all kinds but the lamp's
    "kind": Key(one_of(*SIM_FAULT_KINDS), f"one of {list(SIM_FAULT_KINDS)}"),
    "at_sample": Key(is_natural, "a plan sample index >= 0"),
    "level": Key(lambda v: is_number(v) and 0.0 < v < 1.0, "a number in (0, 1) (the dimmed lamp's intensity "
                 "factor)", ABSENT),  # lamp_dim only
    "duration_s": Key(lambda v: is_number(v) and v > 0, "a number of nominal seconds > 0", ABSENT),  # timed kinds
}
# the keys each kind needs, and the keys it must not have (cross-key rules after the table)
_NEEDS = {"lamp_dim": ("level", "duration_s"), "lamp_cut": ("duration_s",), "interlock_open": ("axis", "duration_s"),
          "silent": ("axis", "duration_s")}
_REFUSES = {"lamp_cut": ("axis", "level"), "lamp_dim": ("axis",), "interlock_open": ("level",), "silent": ("level",)}


def _faults(value, source, keypath: str) -> list:
    """Each fault checked by the table, then by its kind: a device fault names an axis; a timed
    fault its duration (and a dimmed lamp its level)."""
    faults = check_items(value, _FAULT_KEYS, source, keypath)
    for i, fault in enumerate(faults):
        kind = fault["kind"]
        for key in _NEEDS.get(kind, ("axis",)):
            if key not in fault:
                raise ConfigError(source, f"{keypath}[{i}].{key}", f"{_FAULT_KEYS[key].expected} (kind {kind})",
                                  "nothing")
        for key in _REFUSES.get(kind, ("level", "duration_s")):
            if key in fault:
                raise ConfigError(source, f"{keypath}[{i}].{key}", f"no {key} for kind {kind}", fault[key])
    return faults
SIM_KEYS = {
    "clock_speedup": Key(lambda v: is_number(v) and v > 0, "a number > 0 (simulated seconds per real second)", 1.0),
    "seed": Key(is_natural, "an integer >= 0", 0),
    "camera": Key(is_mapping, "a mapping of simulated camera keys", ABSENT, nested=_camera),
    "lamp": Key(is_mapping, "a mapping with drift_per_hour", {},
                nested=lambda v, source, kp: check_section(v, _LAMP_KEYS, source, kp)),
    "faults": Key(is_list, "a list of {axis, kind, at_sample} mappings", [], nested=_faults),
    "misalignment_deg": Key(is_mapping, "a mapping {axis name: degrees}", {}, nested=check_values),
}


# The ``twins:`` section of a rig file written by ``goniofrost sim --write-rig`` (sim.rig_file): a
# rig that is real to every program but whose devices are running twins. A dry run compares moves
# on their clock, and a capture names the simulated material to the camera service.
TWINS_KEYS = {
    "clock_speedup": Key(lambda v: is_number(v) and v > 0, "a number > 0 (the twins' simulated seconds per "
                                                           "real second)"),
    "camera_service_port": Key(lambda v: is_natural(v) and 0 < v < 65536,
                               "the loopback port of the simulated camera's service (1 to 65535)"),
}


def validate_twins_section(section, source, keypath: str = "twins") -> dict:
    """Check a rig file's ``twins`` mapping (see TWINS_KEYS); return a copy."""
    return check_section(section, TWINS_KEYS, source, keypath)


def validate_sim_section(section, source, keypath: str = "sim") -> dict:
    """Check a rig file's ``sim`` mapping; return a copy with the defaults filled in.

    Raises ConfigError(source, KEYPATH.KEY, expected, found) on the first unknown key or bad value.
    """
    return check_section(section, SIM_KEYS, source, keypath)


def check_fault_axes(faults, axis_names, source, keypath: str = "sim.faults") -> None:
    """ConfigError when a checked fault names no axis of ``axis_names``."""
    for i, fault in enumerate(faults):
        if "axis" in fault and fault["axis"] not in axis_names:
            raise ConfigError(source, f"{keypath}[{i}].axis", f"one of the rig's axes {sorted(axis_names)}",
                              fault["axis"])


def check_sim_against_rig(rig) -> None:
    """The checks of a loaded rig's ``sim`` section that need its other sections (planner Rig)."""
    faults = (rig.sim or {}).get("faults", [])
    check_fault_axes(faults, rig.axes, rig.source)
    for i, fault in enumerate(faults):
        protocol = str(rig.axes[fault["axis"]].driver.get("protocol", "")) if "axis" in fault else ""
        if fault["kind"] in ("interlock_open", "silent") and not protocol.startswith("modbus"):
            raise ConfigError(rig.source, f"sim.faults[{i}].axis", f"a Modbus axis (kind {fault['kind']})",
                              fault["axis"])
    check_axes((rig.sim or {}).get("misalignment_deg", {}), list(rig.joint_names), rig.source)
