"""The label a capture is given: ``session_label`` joins the rig file's ``lab:`` section
(``goniofrost.rig.lab``) to the command line's operator, sample id and notes into the
``SessionLabel`` (``goniofrost.capture.records``) the journal keeps.
"""
from __future__ import annotations

from goniofrost.capture.records import SessionLabel
from goniofrost.rig.lab import check_text


def session_label(rig, operator=None, sample_id=None, notes=(), queue=None, source="command line") -> SessionLabel:
    """The label of a session on ``rig`` (a loaded rig: its ``lab`` section) with what the operator
    gave; ConfigError naming ``source`` and the option for a text that is empty or on several lines."""
    lab = getattr(rig, "lab", None) or {}
    notes = tuple(check_text(n, source, "--note") for n in (notes or ()))
    return SessionLabel(operator=check_text(operator, source, "--operator"),
                        sample_id=check_text(sample_id, source, "--sample-id"), notes=notes,
                        lab=lab.get("lab"), lens=lab.get("lens"), lamp=lab.get("lamp"), queue=queue)
