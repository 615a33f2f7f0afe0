"""Suspenders: conditions that pause a capture at its next safe point until they clear.

The lamp's photodiode below a floor (``lamp_floor``, relative to nominal), its drift beyond a limit
(``lamp_drift``, relative to the run's first reading), a device that stopped answering
(``device_silent``), an open interlock (``interlock``: a Modbus discrete input of a drive, 1 =
closed). Pure: a ``Reading`` in, a ``SuspendReason`` or None out; reading the devices and waiting
is ``goniofrost.capture.suspension``'s. ``SUSPENDER_KEYS`` is the key table of the rig file's
``suspenders:`` section (absent: no suspender), with ``hold_clear_s``, ``poll_s``, ``resume``
(``auto`` or ``operator``) and ``give_up_s``; docs/explanations/suspenders.md has an example.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

from goniofrost.core.errors import ConfigError
from goniofrost.core.config_check import (ABSENT, Key, check_section, is_bool, is_int, is_mapping, is_number,
                                          is_text, one_of)


class SuspendReason(str, enum.Enum):
    """Why a run is suspended (journaled as is; readers compare members, never words)."""

    LAMP_LOW = "lamp_low"              # photodiode below lamp_floor
    LAMP_DRIFT = "lamp_drift"          # photodiode beyond lamp_drift of the run's first reading
    DEVICE_SILENT = "device_silent"    # a device did not answer its reading
    INTERLOCK_OPEN = "interlock_open"  # the interlock input reads 0

    def __str__(self) -> str:
        return self.value


class ResumeMode(str, enum.Enum):
    """How a suspended run resumes once its conditions held clear for ``hold_clear_s``."""

    AUTO = "auto"          # by itself
    OPERATOR = "operator"  # when the operator says so (``SuspendWatch.resume``)


@dataclass(frozen=True)
class Reading:
    """What the suspenders look at: ``photodiode`` relative to nominal (None: not read),
    ``reference`` the run's first photodiode reading, ``silent`` the name of a device that did not
    answer (None: all answered), ``interlock_closed`` (None: no interlock on this rig)."""

    photodiode: float | None = None
    reference: float | None = None
    silent: str | None = None
    interlock_closed: bool | None = None


@dataclass(frozen=True)
class Suspenders:
    """The checked ``suspenders:`` section: thresholds (None: that condition is off), times in
    session-clock seconds, the resume mode and the interlock ({device, input} or None)."""

    lamp_floor: float | None = None
    lamp_drift: float | None = None
    device_silent: bool = False
    interlock: dict | None = None
    hold_clear_s: float = 10.0
    poll_s: float = 1.0
    resume: ResumeMode = ResumeMode.AUTO
    give_up_s: float = 600.0

    @classmethod
    def from_section(cls, section) -> "Suspenders | None":
        """From a checked section (``validate_suspenders_section``); None when it is empty."""
        if not section:
            return None
        return cls(section.get("lamp_floor"), section.get("lamp_drift"), bool(section["device_silent"]),
                   section.get("interlock"), float(section["hold_clear_s"]), float(section["poll_s"]),
                   ResumeMode(section["resume"]), float(section["give_up_s"]))

    @property
    def reads_lamp(self) -> bool:
        return self.lamp_floor is not None or self.lamp_drift is not None or self.device_silent

    def check(self, reading: Reading) -> SuspendReason | None:
        """The first condition ``reading`` violates, in the order of SuspendReason; None: all clear."""
        if reading.silent is not None:
            return SuspendReason.DEVICE_SILENT if self.device_silent else None
        pd = reading.photodiode
        if self.lamp_floor is not None and pd is not None and pd < self.lamp_floor:
            return SuspendReason.LAMP_LOW
        if self.lamp_drift is not None and pd is not None and reading.reference:
            if abs(pd / reading.reference - 1.0) > self.lamp_drift:
                return SuspendReason.LAMP_DRIFT
        if reading.interlock_closed is False:
            return SuspendReason.INTERLOCK_OPEN
        return None


def _fraction(value) -> bool:
    return is_number(value) and 0.0 < value < 1.0


_INTERLOCK_KEYS = {
    "device": Key(is_text, "the name of a Modbus axis of this rig (the drive with the input)"),
    "input": Key(lambda v: is_int(v) and 0 <= v <= 0xFFFE, "a discrete input address 0..0xFFFE"),
}
SUSPENDER_KEYS = {
    "lamp_floor": Key(_fraction, "a number in (0, 1) (photodiode relative to nominal)", ABSENT),
    "lamp_drift": Key(_fraction, "a number in (0, 1) (relative change from the run's first reading)", ABSENT),
    "device_silent": Key(is_bool, "true or false", True),
    "interlock": Key(is_mapping, "a mapping {device, input}", ABSENT,
                     nested=lambda v, source, kp: check_section(v, _INTERLOCK_KEYS, source, kp)),
    "hold_clear_s": Key(lambda v: is_number(v) and v >= 0, "a number of seconds >= 0", 10.0),
    "poll_s": Key(lambda v: is_number(v) and v > 0, "a number of seconds > 0", 1.0),
    "resume": Key(one_of(*(m.value for m in ResumeMode)), f"one of {[m.value for m in ResumeMode]}", "auto"),
    "give_up_s": Key(lambda v: is_number(v) and v > 0, "a number of seconds > 0", 600.0),
}


def validate_suspenders_section(section, source, keypath: str = "suspenders") -> dict:
    """The rig file's ``suspenders`` mapping checked, defaults filled in (ConfigError on the first problem)."""
    return check_section(section, SUSPENDER_KEYS, source, keypath)


def check_suspenders_against_rig(rig) -> None:
    """ConfigError when the interlock names no Modbus axis of the loaded rig (planner Rig)."""
    interlock = (getattr(rig, "suspenders", None) or {}).get("interlock")
    if interlock is None:
        return
    modbus = sorted(name for name, axis in rig.axes.items() if str(axis.driver.get("protocol", "")).startswith("modbus"))
    if interlock["device"] not in modbus:
        raise ConfigError(rig.source, "suspenders.interlock.device", f"one of the rig's Modbus axes {modbus}",
                          interlock["device"])
