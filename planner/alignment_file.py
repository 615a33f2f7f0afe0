"""ALIGNMENT.json: the record of the rig's alignment, each axis's zero offset as ``goniofrost align``
measured it (the fit itself is ``planner.alignment``).

ALIGNMENT.json holds at least ``"offsets_deg": {AXIS_NAME: degrees, ...}`` for every axis of the
rig: an axis whose reading is q stands physically at q + offset (so on a simulated rig built wrong
on purpose, the offsets equal the injected ``sim.misalignment_deg``). The kinematics
(``planner.kinematics``) add the offsets to the readings and take them off the targets. A plan
records the alignment it was scheduled with (``record()``), and a capture refuses another one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from goniofrost.core.cache import content_key
from goniofrost.core.config_check import read_json_file
from goniofrost.core.errors import ConfigError

# An offset this large is not a zero error but a wrong axis, a wrong sign or a wrong file.
MAX_OFFSET_DEG = 10.0


@dataclass(frozen=True)
class Alignment:
    """Zero offsets by axis name (degrees), where they came from, and their content hash."""

    offsets_deg: dict
    source: str
    hash: str

    def record(self) -> dict:
        """What a plan stores about its alignment (and what a capture compares)."""
        return {"file": self.source, "hash": self.hash, "offsets_deg": dict(self.offsets_deg)}


def alignment_hash(offsets_deg: Mapping[str, float]) -> str:
    """16 hex digits of the offsets' canonical form (the same offsets: the same alignment)."""
    return content_key("alignment-v1", {k: float(v) for k, v in sorted(offsets_deg.items())})[:16]


def load_alignment(path, axis_names) -> Alignment:
    """Read ALIGNMENT.json; ConfigError (file, key, expected, found) unless it holds a finite offset
    within +-MAX_OFFSET_DEG for every axis in ``axis_names`` and no other."""
    path = Path(path)
    doc = read_json_file(path, "an ALIGNMENT.json file (goniofrost align --out FILE)")
    offsets = doc.get("offsets_deg") if isinstance(doc, dict) else None
    if not isinstance(offsets, dict):
        raise ConfigError(path, "offsets_deg", "a mapping {axis name: degrees}", offsets)
    names = list(axis_names)
    for name in offsets:
        if name not in names:
            raise ConfigError(path, f"offsets_deg.{name}", f"an axis of the rig ({', '.join(names)})", name)
    out = {}
    for name in names:
        value = offsets.get(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or abs(value) > MAX_OFFSET_DEG:
            found = "nothing" if name not in offsets else value
            raise ConfigError(path, f"offsets_deg.{name}", f"a zero offset in degrees within +-{MAX_OFFSET_DEG:g}", found)
        out[name] = float(value)
    return Alignment(out, str(path), alignment_hash(out))
