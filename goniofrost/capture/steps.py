"""The capture session as a plan: the ordered steps, with no side effects.

``session_steps`` only says what to do (home, lamp on, calibrate, then per remaining sample:
move, measure, commit; finally lamp off). It never touches a device, a file or a clock, so it
is tested by comparing the steps it yields, and the engine (``goniofrost.capture.engine``) that executes
them owns every side effect. Samples already in the journal are skipped, so a resumed session
never repeats one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Mapping


@dataclass(frozen=True)
class Home:
    """Home every axis (in joint order)."""

    axes: tuple[str, ...]


@dataclass(frozen=True)
class LampOn:
    """Switch the lamp on (and let the engine note the photodiode reading)."""


@dataclass(frozen=True)
class LampOff:
    """Switch the lamp off at the end of the session."""


@dataclass(frozen=True)
class Calibrate:
    """Take the calibration frames (dark, flat, white reference at the pose just reached) and
    journal the record."""


@dataclass(frozen=True)
class Move:
    """Move every axis to ``joints`` (axis name -> degrees) for plan sample ``index`` (None: the
    white-reference pose of the calibration).

    Axes already within tolerance of their target are not commanded (the Axis contract).
    """

    index: int | None
    joints: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class Measure:
    """Capture and calibrate plan sample ``index`` at the pose just reached."""

    index: int


@dataclass(frozen=True)
class Commit:
    """Journal plan sample ``index`` (one transaction) and append it to samples.csv."""

    index: int


Step = Home | LampOn | LampOff | Calibrate | Move | Measure | Commit


def session_steps(samples: Iterable[Mapping], axes: Iterable[str], done: Iterable[int] = (),
                  calibrated: bool = False, white_joints: Mapping | None = None) -> Iterator[Step]:
    """Yield the steps of a capture session.

    ``samples``: the plan's samples in capture order, each with ``joints`` {axis: deg};
    ``axes``: axis names in joint order; ``done``: plan indices already journaled;
    ``calibrated``: a calibration record is already journaled (a resumed session keeps it);
    ``white_joints``: the pose {axis: deg} that shows the white reference tile at its nominal
    angles (required unless ``calibrated``).
    A session with nothing left to capture yields no step at all.
    """
    samples, axes, done = list(samples), tuple(axes), set(done)
    if not remaining(len(samples), done):
        return  # nothing left to capture: touch no device
    yield Home(axes)
    yield LampOn()
    if not calibrated:
        yield Move(None, tuple((name, float(white_joints[name])) for name in axes))
        yield Calibrate()
    for index, sample in enumerate(samples):
        if index in done:
            continue
        yield Move(index, tuple((name, float(sample["joints"][name])) for name in axes))
        yield Measure(index)
        yield Commit(index)
    yield LampOff()


def remaining(n_samples: int, done: Iterable[int]) -> list[int]:
    """Plan indices still to capture, in plan order."""
    done = set(done)
    return [i for i in range(n_samples) if i not in done]
