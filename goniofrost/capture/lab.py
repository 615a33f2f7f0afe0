"""A session's lab metadata: the rig file's ``lab:`` section and the label a capture is given.

The ``lab:`` section holds what does not change from sample to sample (the lab, the lens, the
lamp); it is checked with the project's key tables (``goniofrost.core.config_check``) when the
rig file is loaded. ``session_label`` joins it to the command line's operator, sample id and
notes into the ``SessionLabel`` (``goniofrost.capture.records``) the journal keeps.
"""
from __future__ import annotations

from goniofrost.core.config_check import Key, KeyTable, check_section
from goniofrost.core.errors import ConfigError
from goniofrost.capture.records import SessionLabel


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


def session_label(rig, operator=None, sample_id=None, notes=(), queue=None, source="command line") -> SessionLabel:
    """The label of a session on ``rig`` (a loaded rig: its ``lab`` section) with what the operator
    gave; ConfigError naming ``source`` and the option for a text that is empty or on several lines."""
    lab = getattr(rig, "lab", None) or {}
    notes = tuple(check_text(n, source, "--note") for n in (notes or ()))
    return SessionLabel(operator=check_text(operator, source, "--operator"),
                        sample_id=check_text(sample_id, source, "--sample-id"), notes=notes,
                        lab=lab.get("lab"), lens=lab.get("lens"), lamp=lab.get("lamp"), queue=queue)
