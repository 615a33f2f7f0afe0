"""What a paused capture holds: the rig file's ``pause:`` section (``PAUSE_KEYS``).

A capture paused by the operator (``POST /api/pause``) waits at its next safe point, every axis
at rest. The lamp stays on (``lamp: keep``, the default) or is switched off and, at the resume,
on again; the run then waits until the photodiode reads within ``lamp_tolerance`` of its reading
before the pause, at most ``warmup_s``, else it ends as a fault::

    pause:
      lamp: off              # keep (default) or off
      lamp_tolerance: 0.02   # relative to the reading before the pause
      warmup_s: 120          # session-clock seconds
      poll_s: 1              # session-clock seconds between readings
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

from goniofrost.core.config_check import Key, check_section, is_number, one_of


class PauseLamp(str, enum.Enum):
    """What the lamp does while a capture is paused."""

    KEEP = "keep"  # stays on
    OFF = "off"    # off for the pause, on again (and back within lamp_tolerance) before the next sample


PAUSE_KEYS = {
    "lamp": Key(one_of(*(m.value for m in PauseLamp)), f"one of {[m.value for m in PauseLamp]} (the lamp while "
                "a capture is paused; axes always stay at rest, holding their position)", "keep"),
    "lamp_tolerance": Key(lambda v: is_number(v) and 0 < v < 1, "a number in (0, 1) (relative to the photodiode's "
                          "reading before the pause, to read within once the lamp is on again)", 0.02),
    "warmup_s": Key(lambda v: is_number(v) and v > 0, "a number of seconds > 0 (session clock; the lamp "
                    "may take this long to come back after a pause with lamp: off)", 120.0),
    "poll_s": Key(lambda v: is_number(v) and v > 0, "a number of seconds > 0 (session clock, between "
                  "photodiode readings while the lamp comes back)", 1.0),
}


@dataclass(frozen=True)
class PauseHold:
    """The checked ``pause:`` section (module doc); seconds of the session clock."""

    lamp: PauseLamp = PauseLamp.KEEP
    lamp_tolerance: float = 0.02
    warmup_s: float = 120.0
    poll_s: float = 1.0

    @classmethod
    def of_rig(cls, rig) -> "PauseHold":
        """The rig's (a loaded rig with ``pause``: its checked section, {} when absent)."""
        section = validate_pause_section(getattr(rig, "pause", None) or {}, getattr(rig, "source", "rig file"))
        return cls(PauseLamp(section["lamp"]), float(section["lamp_tolerance"]), float(section["warmup_s"]),
                   float(section["poll_s"]))


def validate_pause_section(section, source, keypath: str = "pause") -> dict:
    """The rig file's ``pause`` mapping checked, defaults filled in (ConfigError on the first problem)."""
    return check_section(section, PAUSE_KEYS, source, keypath)
