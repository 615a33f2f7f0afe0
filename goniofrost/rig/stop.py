"""The one stop path of a rig: stop every axis and confirm each one at rest, and say how it went.

``stop_axes`` commands every axis to stop, then confirms each (``AxisStop`` per axis); the capture
engine calls it on any failure, Ctrl-C or stop request (``goniofrost.capture.executor``), and the
hardware opener, through ``release_stop`` (only what is not confirmed stopped yet: one stop per
axis per exit), on leaving a rig. ``stop_text`` is the stops in one sentence for the operator.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping

from goniofrost.rig.contract import Axis

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AxisStop:
    """How one axis took the stop: ``confirmed`` when the device reported it at rest (at
    ``position_deg``); otherwise ``under_way`` tells whether a move was under way, ``moving_to``
    its target when known (the axis may still be going there), and ``error`` why the stop was not
    confirmed."""

    axis: str
    confirmed: bool
    position_deg: float | None = None
    under_way: bool = False
    moving_to: float | None = None
    error: str | None = None

    def text(self) -> str:
        """One clause for the operator, e.g. "sample_yaw did not confirm the stop: it may still be
        moving towards 56.7 deg"."""
        if self.confirmed:
            return f"{self.axis} stopped at {self.position_deg:.2f} deg"
        if self.under_way and self.moving_to is not None:
            return f"{self.axis} did not confirm the stop: it may still be moving towards {self.moving_to:.1f} deg"
        if self.under_way:
            return f"{self.axis} did not confirm the stop: it may still be moving"
        return f"{self.axis} did not confirm the stop (it was not moving as far as this session knows)"


def stop_axes(axes: Mapping[str, Axis], moving_to: Mapping[str, float | None] | None = None) -> list[AxisStop]:
    """Command every axis to stop, then confirm each one is at rest; never raise.

    ``moving_to``: {axis: target degrees, or None when unknown} of the moves under way (they name
    where an unconfirmed axis may still be going). Every axis is tried whatever the others do; an
    axis that is not connected cannot be confirmed. Problems are also logged.
    """
    moving_to = moving_to or {}
    errors = {}
    for name, axis in axes.items():
        try:
            if not axis.connected:
                raise ConnectionError("not connected")
            axis.stop()
        except Exception as exc:  # noqa: BLE001 - keep stopping the other axes
            log.warning("stop %s failed: %s", name, exc)
            errors[name] = str(exc)
    stops = []
    for name, axis in axes.items():
        if name not in errors:  # a stop that could not be sent cannot be confirmed either
            try:
                stops.append(AxisStop(name, True, position_deg=float(axis.confirm_stopped())))
                continue
            except Exception as exc:  # noqa: BLE001
                log.warning("confirming the stop of %s failed: %s", name, exc)
                errors[name] = str(exc)
        stops.append(AxisStop(name, False, under_way=name in moving_to, moving_to=moving_to.get(name),
                              error=errors[name]))
    return stops


def release_stop(axes: Mapping[str, Axis]) -> list[AxisStop]:
    """On leaving a rig: stop and confirm (``stop_axes``) every axis not confirmed at rest since
    its last motion command; never raise.

    After a fault the engine's stop has already confirmed the axes it could: each axis is stopped
    once per exit, and one whose stop failed is tried again here. On a normal exit nothing has
    stopped the axes: every one is stopped here. Reads the drivers' ``confirmed_at_rest_deg``
    (``drivers.axis``). The lamp is the engine's (its plans end with it off, a fault switches it
    off); a console command may leave it on on purpose (``rig lamp on``).
    """
    rested = {name: axis.confirmed_at_rest_deg for name, axis in axes.items()}
    stopped = {s.axis: s for s in stop_axes({name: a for name, a in axes.items() if rested[name] is None})}
    return [stopped.get(name) or AxisStop(name, True, position_deg=rested[name]) for name in axes]


def stop_text(stops: list[AxisStop]) -> str:
    """The stops in one sentence: the confirmed ones together, then each unconfirmed one."""
    done = [s for s in stops if s.confirmed]
    parts = []
    if done:
        parts.append("stopped " + ", ".join(f"{s.axis} at {s.position_deg:.2f} deg" for s in done))
    parts += [s.text() for s in stops if not s.confirmed]
    return "; ".join(parts) if parts else "no axis to stop"
