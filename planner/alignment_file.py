"""ALIGNMENT.json: each axis's zero offset in degrees, as ``goniofrost align`` measured it.

Holds ``"offsets_deg": {AXIS_NAME: degrees}`` for every axis and an optional ``"version"``. An axis
reading q stands physically at q + offset. Entry points: ``Alignment``, ``load_alignment``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from goniofrost.core.cache import content_key
from goniofrost.core.config_check import ABSENT, Key, check_section, is_mapping, is_number, read_json_file
from goniofrost.core.errors import ConfigError

# An offset this large is not a zero error but a wrong axis, a wrong sign or a wrong file.
MAX_OFFSET_DEG = 10.0
VERSION = 1   # the ALIGNMENT.json format goniofrost align writes and this module reads


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


def load_alignment(path, axis_names, rig_name: str | None = None) -> Alignment:
    """Read ALIGNMENT.json; ConfigError (file, key, expected, found) unless it holds a finite offset
    within +-MAX_OFFSET_DEG for every axis in ``axis_names`` and no other, and, when both are given,
    the rig it names (``rig.name``) is ``rig_name``. Other top-level keys are kept and not read.
    """
    path = Path(path)
    doc = read_json_file(path, "an ALIGNMENT.json file (goniofrost align --out FILE)")
    measured_on = doc.get("rig", {}).get("name") if isinstance(doc, dict) and isinstance(doc.get("rig"), dict) else None
    if rig_name is not None and measured_on is not None and measured_on != rig_name:
        raise ConfigError(path, "rig.name", f"{rig_name!r}, the rig it is used on (an alignment is measured per rig: "
                          "run goniofrost align on this one)", measured_on)
    offset = Key(lambda v: is_number(v) and abs(v) <= MAX_OFFSET_DEG,
                 f"a zero offset in degrees within +-{MAX_OFFSET_DEG:g}")
    table = {"version": Key(lambda v: v == VERSION and not isinstance(v, bool), f"{VERSION} (the format this "
                            "goniofrost reads: an ALIGNMENT.json of goniofrost align)", ABSENT),
             "offsets_deg": Key(is_mapping, "a mapping {axis name: degrees}",
                                nested=lambda v, source, kp: check_section(v, {n: offset for n in axis_names},
                                                                           source, kp))}
    offsets = check_section(doc, table, path, "", open_keys=True)["offsets_deg"]
    out = {name: float(value) for name, value in offsets.items()}
    return Alignment(out, str(path), alignment_hash(out))
