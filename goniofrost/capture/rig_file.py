"""Load a rig file with every section checked by the package that owns it.

``planner.rig`` checks the geometry and the axes' motion keys; the ``driver`` sections are checked
by ``drivers.config.validate_driver_section``, the ``camera`` section by ``calib.config`` and the
``sim`` section by ``sim.config``. Each validator is imported when a rig is loaded; one that is
named here but cannot be found is an ImportError, never a section left unchecked.
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
    """Every validator of VALIDATORS, by section name; ImportError when one does not exist."""
    found = {}
    for section, (module_name, func_name) in VALIDATORS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            raise ImportError(f"the rig file's {section!r} sections cannot be checked: its validator "
                              f"{module_name}.{func_name} is missing ({exc})") from exc
        func = getattr(module, func_name, None)
        if not callable(func):
            raise ImportError(f"the rig file's {section!r} sections cannot be checked: module "
                              f"{module_name} has no function {func_name}")
        found[section] = func
    return found


def load_checked_rig(path: str | Path) -> Rig:
    """Read and fully validate a rig file (raises goniofrost.core.errors.ConfigError)."""
    return _load_rig(path, section_validators())
