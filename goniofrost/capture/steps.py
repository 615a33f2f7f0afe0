"""The vocabulary of a capture plan: every step a session takes, and what each step gives back.

A plan is a generator of these frozen steps that never touches a device, a file or a clock: the
executor sends each step's result back in (``frame = yield Expose(...)``), which is how a plan
adapts (the exposure bracket) and carries its own state. ``drive`` runs a plan against any
executor: the engine, a camera bench, or a test's scripted results.

Step -> result: ``Home``/``Move`` -> ``Reached``; ``Expose`` -> ``Frame``; ``LampOn`` -> the
photodiode reading; ``SaveCalibration`` -> the saved CalibrationRecord; every other step -> None.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Generator

from calib.record import CalibrationRecord
from goniofrost.capture.records import NotMeasuredRecord, SampleRecord


@dataclass(frozen=True)
class Home:
    """Home every axis of ``axes`` (in joint order), all together."""

    axes: tuple[str, ...]


@dataclass(frozen=True)
class Move:
    """Move every axis to ``joints`` ((axis name, degrees), in joint order), all together, for plan
    sample ``index`` (None: the white-reference pose of the calibration).

    Axes already within tolerance of their target are not commanded (the Axis contract).
    """

    index: int | None
    joints: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class LampOn:
    """Switch the lamp on (and read the photodiode)."""


@dataclass(frozen=True)
class LampOff:
    """Switch the lamp off (dark frames; the end of the session)."""


@dataclass(frozen=True)
class SetTarget:
    """Put ``target`` ("sample", "white" or "flat") in front of the camera."""

    target: str


@dataclass(frozen=True)
class Expose:
    """Take one RAW frame of ``exposure_s`` seconds into ``file`` (relative to the session folder),
    reading the monitor photodiode before and after. ``index``: the plan sample the frame
    belongs to (None: a calibration frame)."""

    exposure_s: float
    file: str
    index: int | None = None


@dataclass(frozen=True)
class Phase:
    """Start a part of the session (``"calibration"``, ``"samples"``): journaled and timed."""

    name: str


@dataclass(frozen=True)
class SaveCalibration:
    """Save the calibration arrays into ``folder`` (relative to the session folder) and journal the
    record. Two SaveCalibration steps compare equal whatever their arrays (plans are compared
    step by step; the record is checked on its own)."""

    record: CalibrationRecord = field(compare=False)
    folder: str = "calibration"


@dataclass(frozen=True)
class Assess:
    """The decision after a batch of a capture with a target error (no device action): what the
    ``samples`` measured so far say about the error and what the plan does next (``decision``:
    "continue", "target reached" or "plan used up"; see capture.target).

    predicted_error: the median estimate of the log-relative MSE; bound: the calibrated upper
    bound at ``confidence`` (None when none can be given); out_of_model: the features beyond
    every held-out training material (``frost.confidence.FEATURE_NAMES``; () if none); scope:
    the error assessed (``frost.scene_error``: "brdf", the whole BRDF's; "scene", the error in the
    scene's use of a plan made with a usage map); design: when "design" is out of the model, (m,
    its log design error, the lowest and highest of the calibration's designs at m, the m they are
    of: ``frost.confidence.design_detail``), else None.
    """

    batch: int
    samples: int
    predicted_error: float
    target: float
    decision: str
    bound: float | None = None
    confidence: float = 0.95
    out_of_model: tuple[str, ...] = ()
    scope: str = "brdf"
    not_measured: int = 0   # of the ``samples``, those without a value (left out of the assessment)
    design: tuple | None = None


@dataclass(frozen=True)
class WhiteCheck:
    """The decision after the white reference was re-measured with a kept calibration's darks and
    flat field (a queue's next sample; no device action): ``drift`` the largest relative change
    of the white scale over the channels, ``limit`` the queue's threshold, ``decision`` "reuse"
    (the darks and flat field are kept, the new white scale used) or "recalibrate"."""

    drift: float
    limit: float
    decision: str


@dataclass(frozen=True)
class Commit:
    """Journal one sample (one transaction; the engine stamps ``committed_utc``): a measured one
    (SampleRecord), also appended to samples.csv, or one the rig could not measure
    (NotMeasuredRecord: journaled with its reason, no value)."""

    record: SampleRecord | NotMeasuredRecord

    @property
    def index(self) -> int:
        return self.record.plan_index


Step = (Home | Move | LampOn | LampOff | SetTarget | Expose | Phase | SaveCalibration | Assess | WhiteCheck
        | Commit)


@dataclass(frozen=True)
class Reached:
    """Where a Home or Move left the axes: ``joints`` {axis: degrees read back}; ``seconds`` of motion
    on the session clock (the axes' motion profiles on a simulated rig); ``started_utc`` Unix time."""

    joints: dict
    seconds: float
    started_utc: float


@dataclass(frozen=True)
class Frame:
    """One RAW frame taken by an Expose step: the file actually written (``path``), the exposure (s),
    the decoded image (``raw``: drivers.rawfile.RawImage), the lamp level relative to nominal
    (mean of the photodiode before and after), ``seconds`` on the session clock (the exposure
    time on a simulated rig) and ``wall_s`` real seconds inside the camera."""

    path: Path
    exposure_s: float
    raw: Any
    lamp_relative: float
    seconds: float
    wall_s: float


Plan = Generator[Step, Any, Any]


def drive(plan: Plan, execute: Callable[[Step], Any]) -> Any:
    """Run ``plan``: execute each step it yields and send the result back; return the plan's value."""
    result = None
    while True:
        try:
            step = plan.send(result)
        except StopIteration as stop:
            return stop.value
        result = execute(step)


def step_detail(step: Step) -> dict:
    """The step's fields as JSON-safe values, for the journal (a Commit: its plan index only)."""
    if isinstance(step, Commit):
        return {"index": step.index}
    return {f.name: getattr(step, f.name) for f in fields(step) if f.compare}


def step_summary(step: Step, result) -> dict:
    """What the journal keeps of a step's ``result`` (JSON-safe; {} for a step without one)."""
    if isinstance(step, (Home, Move)):
        return {"joints": result.joints, "seconds": result.seconds}
    if isinstance(step, LampOn):
        return {"photodiode": result}
    if isinstance(step, Expose):
        return {"path": str(result.path), "lamp_relative": result.lamp_relative, "seconds": result.seconds}
    if isinstance(step, (Assess, WhiteCheck)):
        return asdict(step)
    if isinstance(step, SaveCalibration):
        return {"arrays": str(result.path), "sha256": result.sha256}
    if isinstance(step, Commit) and isinstance(step.record, NotMeasuredRecord):
        return {"snr": step.record.best_snr, "status": str(step.record.reason)}
    if isinstance(step, Commit):
        return {"snr": step.record.snr, "status": step.record.status}
    return {}


# the steps a resumed simulated run starts again from: the simulation's state is journaled with them
CHECKPOINTS = (SaveCalibration, Commit)
