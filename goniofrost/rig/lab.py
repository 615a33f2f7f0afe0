"""The rig file's ``lab:`` section: what does not change from sample to sample (the lab, the lens,
the lamp), checked with the project's key tables (``goniofrost.core.config_check``) when the rig
file is loaded. ``goniofrost.capture.lab`` joins it to a session's label.
"""
from __future__ import annotations

from goniofrost.core.config_check import Key, KeyTable, check_section
from goniofrost.core.errors import ConfigError


def _text_or_none(value) -> bool:
    return value is None or (isinstance(value, str) and value.strip() != "" and "\n" not in value)


TEXT = "a one-line text"
LAB_KEYS: KeyTable = {
    "lab": Key(_text_or_none, TEXT + " (the lab's name)", None),
    "lens": Key(_text_or_none, TEXT + " (the camera's lens)", None),
    "lamp": Key(_text_or_none, TEXT + " (the light source)", None),
}


def validate_lab_section(section, source, keypath: str = "lab") -> dict:
    """The rig file's ``lab`` mapping checked, absent keys None (ConfigError on the first problem)."""
    return check_section(section, LAB_KEYS, source, keypath)


def check_text(value, source, keypath: str) -> str | None:
    """A one-line, non-empty text (an operator, a sample id, a note) or None."""
    if not _text_or_none(value):
        raise ConfigError(source, keypath, TEXT, value)
    return value
