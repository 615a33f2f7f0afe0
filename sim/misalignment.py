"""A simulated rig built wrong on purpose: ``sim.misalignment_deg: {AXIS_NAME: degrees}``.

Each axis physically stands at its encoder reading plus the offset, so ``goniofrost align`` should
find the same numbers.
"""
from __future__ import annotations

from goniofrost.core.config_check import is_number
from goniofrost.core.errors import ConfigError

MAX_MISALIGNMENT_DEG = 10.0


def check_values(section, source, keypath: str = "sim.misalignment_deg") -> dict:
    """``{name: degrees}`` with every value a number within +-MAX_MISALIGNMENT_DEG (the names are
    checked against the rig's axes by ``check_axes``)."""
    out = {}
    for name, value in section.items():
        if not is_number(value) or abs(value) > MAX_MISALIGNMENT_DEG:
            raise ConfigError(source, f"{keypath}.{name}",
                              f"a zero error in degrees within +-{MAX_MISALIGNMENT_DEG:g}", value)
        out[str(name)] = float(value)
    return out


def check_axes(section, axis_names, source, keypath: str = "sim.misalignment_deg") -> None:
    """ConfigError when a misalignment names no axis of ``axis_names`` (in joint order)."""
    for name in section:
        if name not in axis_names:
            raise ConfigError(source, f"{keypath}.{name}", f"an axis of the rig ({', '.join(axis_names)})", name)


def physical_joints(encoder_deg: dict, misalignment: dict) -> dict:
    """Where the axes physically stand (degrees by axis name) at these encoder readings."""
    return {name: float(value) + misalignment.get(name, 0.0) for name, value in encoder_deg.items()}
