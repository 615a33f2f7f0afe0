"""Load a rig file with every section checked by the package that owns it.

``planner.rig`` checks the geometry and the axes' motion keys; the ``driver`` sections are checked
by ``drivers.config.validate_driver_section``, the ``camera`` and ``sim`` sections by the camera
package's validators. Each validator is imported lazily, and one that does not exist yet is
skipped (its section is then kept as written, unchecked).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable, Mapping

from planner.rig import Rig
from planner.rig import load_rig as _load_rig

# section -> (module, function) of its validator: validator(section, source, keypath) -> None.
VALIDATORS: dict[str, tuple[str, str]] = {
    "driver": ("drivers.config", "validate_driver_section"),
    "camera": ("calib.config", "validate_camera_section"),
    "sim": ("sim.config", "validate_sim_section"),
}


def section_validators() -> dict[str, Callable[[Mapping, str, str], None]]:
    """The validators that exist in this checkout, by section name."""
    found = {}
    for section, (module_name, func_name) in VALIDATORS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise  # the module exists but is broken: let that surface
            continue
        func = getattr(module, func_name, None)
        if callable(func):
            found[section] = func
    return found


def load_checked_rig(path: str | Path) -> Rig:
    """Read and fully validate a rig file (raises goniofrost.core.errors.ConfigError)."""
    return _load_rig(path, section_validators())
