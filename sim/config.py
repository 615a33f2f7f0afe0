"""The rig file's ``sim:`` section: every key the simulated rig reads, declared as data and checked.

``validate_sim_section(section, source, keypath)`` is the validator the rig loader
(``goniofrost.capture.rig_file``) plugs in for ``sim``. An unknown key, a value of the wrong
type or out of range is one ``ConfigError`` naming the file, the key path, what was expected and
what was found. It returns the section with its defaults filled in, so that the simulated rig
reads its defaults from here only.

Keys (``SIM_KEYS``; to add one, add a row)::

    sim:
      clock_speedup: 20.0      # simulated seconds per real second (> 0); default 1
      seed: 0                  # seed of every simulated noise (integer >= 0); default 0
      camera: {...}            # the simulated camera (sim.camera.validate_sim_camera_section)
      lamp:
        drift_per_hour: 0.02   # relative lamp intensity change per simulated hour; default 0.02
      faults:                  # fault drills; default none
        - {axis: sample_yaw, kind: stall, at_sample: 3}   # strikes when sample_yaw next moves
                                                          # at or after plan sample 3, once
        - {axis: camera_arm, kind: miss_reply, at_sample: 1}   # one lost reply: the capture goes on
      misalignment_deg:        # a rig built wrong on purpose (sim.misalignment); default none
        {camera_arm: 0.6, sample_yaw: -1.1, sample_tilt: 0.4}   # axis stands at reading + this

``check_sim_against_rig(rig)`` (a second check the rig loader runs on the loaded rig) checks what
needs the rest of the rig: every fault and every misalignment names one of the rig's axes.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from goniofrost.core.config_check import check_section, is_number
from goniofrost.core.errors import ConfigError

from .faults import DRILL_KINDS
from .misalignment import check_axes, check_values

_ABSENT = object()  # a key without a default stays absent when not given


@dataclass(frozen=True)
class SimKey:
    """One key of the sim section: ``check(value) -> bool``, what a good value is, its default
    (``_ABSENT``: none, the key stays out), and an optional validator of the value's own keys,
    ``nested(value, source, keypath) -> completed value``."""

    check: Callable[[Any], bool]
    expected: str
    default: Any = _ABSENT
    nested: Callable[[Any, str, str], Any] | None = None


def _natural(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _mapping(v) -> bool:
    return isinstance(v, Mapping)


def _camera(section, source: str, keypath: str) -> dict:
    from .camera import validate_sim_camera_section  # the camera owns its keys (imported on use)
    return validate_sim_camera_section(dict(section), source, keypath)


_LAMP_KEYS = {  # key: (check, expected, default)
    "drift_per_hour": (lambda v: is_number(v) and -1.0 <= v <= 1.0,
                       "a number in [-1, 1] (relative intensity change per simulated hour)", 0.02),
}


def _lamp(section, source: str, keypath: str) -> dict:
    return check_section(dict(section), _LAMP_KEYS, source, keypath)


_FAULT_KEYS = {  # key: (check, expected, default; None = required)
    "axis": (lambda v: isinstance(v, str) and v != "", "the name of an axis of this rig", None),
    "kind": (lambda v: v in DRILL_KINDS, f"one of {list(DRILL_KINDS)}", None),
    "at_sample": (_natural, "a plan sample index >= 0", None),
}


def _faults(items, source: str, keypath: str) -> list[dict]:
    return [check_section(item, _FAULT_KEYS, source, f"{keypath}[{i}]") for i, item in enumerate(items)]


SIM_KEYS: dict[str, SimKey] = {
    "clock_speedup": SimKey(lambda v: is_number(v) and v > 0,
                            "a number > 0 (simulated seconds per real second)", 1.0),
    "seed": SimKey(_natural, "an integer >= 0", 0),
    "camera": SimKey(_mapping, "a mapping of simulated camera keys", nested=_camera),
    "lamp": SimKey(_mapping, "a mapping with drift_per_hour", {}, nested=_lamp),
    "faults": SimKey(lambda v: isinstance(v, list), "a list of {axis, kind, at_sample} mappings", [],
                     nested=_faults),
    "misalignment_deg": SimKey(_mapping, "a mapping {axis name: degrees}", {}, nested=check_values),
}


def validate_sim_section(section, source, keypath: str = "sim") -> dict:
    """Check a rig file's ``sim`` mapping; return a copy with the defaults filled in.

    Raises ConfigError(source, KEYPATH.KEY, expected, found) on the first unknown key or bad value.
    """
    if not isinstance(section, Mapping):
        raise ConfigError(source, keypath, "a mapping", section)
    unknown = sorted(set(section) - set(SIM_KEYS))
    if unknown:
        raise ConfigError(source, f"{keypath}.{unknown[0]}", f"one of {sorted(SIM_KEYS)}", unknown[0])
    out = {}
    for key, spec in SIM_KEYS.items():
        if key not in section and spec.default is _ABSENT:
            continue
        value = section.get(key, spec.default)
        if not spec.check(value):
            raise ConfigError(source, f"{keypath}.{key}", spec.expected, value)
        out[key] = spec.nested(value, source, f"{keypath}.{key}") if spec.nested else value
    return out


def check_fault_axes(faults, axis_names, source, keypath: str = "sim.faults") -> None:
    """ConfigError when a checked fault names no axis of ``axis_names``."""
    for i, fault in enumerate(faults):
        if fault["axis"] not in axis_names:
            raise ConfigError(source, f"{keypath}[{i}].axis", f"one of the rig's axes {sorted(axis_names)}",
                              fault["axis"])


def check_sim_against_rig(rig) -> None:
    """The checks of a loaded rig's ``sim`` section that need its other sections (planner Rig)."""
    check_fault_axes((rig.sim or {}).get("faults", []), rig.axes, rig.source)
    check_axes((rig.sim or {}).get("misalignment_deg", {}), list(rig.joint_names), rig.source)
