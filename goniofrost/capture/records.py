"""The typed records of a run: what the engine journals and every reader reads, field by field.

The bottom of ``goniofrost.capture`` (it imports only the rig's ``AxisStop``). Readers match
fields, never sentences: messages and reasons are for people. ``EventKind`` is the kind of every
journal event (a ``str`` enum, stored by value); ``RunStatus`` how a run ended
(``RunEnd.exit_status``; a run with no ``RunEnd`` and no lock held was killed). ``RunStart`` and
``RunEnd`` are one row each per run in the ``runs`` table; ``SampleRecord`` and
``NotMeasuredRecord`` a sample measured or done without a value; ``SafePoint``, ``StepStarting``,
``StepDone``, ``StepFailed`` and ``PlanEnded`` what the engine core hands its subscribers.
"""
from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass, field

from calib.measurement import NotMeasuredReason, why_not_measured
from goniofrost.rig.stop import AxisStop


class EventKind(str, enum.Enum):
    """The kind of a journal event (``Journal.add_event``; ``Journal.events`` returns them)."""

    SESSION = "session"          # a run started or ended (its RunStart / RunEnd are in the runs table)
    HOME = "home"                # axes homed (data: joints reached)
    LAMP = "lamp"                # lamp on/off (data: photodiode; after a stop: off, error)
    CALIBRATION = "calibration"  # the calibration phase started, was saved, or is retaken
    SAMPLES = "samples"          # the sample phase started
    ALIGNMENT = "alignment"      # the alignment phase started
    BATCH = "batch"              # a batch assessed against the target error (data: Assess fields)
    NOT_MEASURED = "not_measured"  # a sample too dark or bright to measure, journaled without a value (data: NotMeasuredRecord)
    FAULT = "fault"              # a device failed (the run ends FAULT)
    ERROR = "error"              # a measurement, camera or output error (the run ends REFUSED or FAULT)
    INTERRUPTED = "interrupted"  # SIGINT/SIGTERM or a stop request (the run ends STOPPED_BY_OPERATOR)
    STOP = "stop"                # how every axis took the stop (data: stops)
    SIMULATION = "simulation"    # a simulated rig's state restored on resume
    DRILL = "drill"              # a simulated rig's fault drill armed or struck
    DEVICE = "device"            # a driver's or protocol library's log record
    SUSPEND = "suspend"          # a suspender paused the run or it resumed (data: the Suspension)

    def __str__(self) -> str:
        return self.value


# the phases a plan names (Phase steps): each journals an event of its own kind
PHASE_KINDS = {"calibration": EventKind.CALIBRATION, "samples": EventKind.SAMPLES,
               "alignment": EventKind.ALIGNMENT, "white_reference": EventKind.CALIBRATION}


class RunStatus(str, enum.Enum):
    """How a run ended (``RunEnd.status``)."""

    FINISHED = "finished"                        # every step of the plan done (every sample captured)
    TARGET_REACHED = "target_reached"            # a target-error capture stopped early: target reached
    PLAN_USED_UP = "plan_used_up"                # a target-error capture measured its whole plan short of the target
    STOPPED_BY_OPERATOR = "stopped_by_operator"  # Ctrl-C, SIGTERM or a stop request (request_stop)
    FAULT = "fault"                              # a device failed (or the program itself)
    REFUSED = "refused"                          # a measurement or an output the run cannot accept

    def __str__(self) -> str:
        return self.value

    @property
    def completed(self) -> bool:
        """True when the run did all it set out to do (nothing to resume)."""
        return self in (RunStatus.FINISHED, RunStatus.TARGET_REACHED, RunStatus.PLAN_USED_UP)


@dataclass(frozen=True)
class RunStart:
    """A run of the engine began: its number (1 for the first of a journal), what program runs
    (``capture``, ``align``, ...), Unix time, the plan's sample count and how many were already done."""

    run: int
    program: str
    started_utc: float
    samples_planned: int
    samples_done: int


@dataclass(frozen=True)
class RunEnd:
    """How a run ended (one per run; a killed run has none).

    ``status``: a RunStatus; ``reason``: words for people (the terminal's message after a stop);
    ``samples_planned``: the plan's samples; ``samples_captured``: journaled by the end of the run
    (all runs; measured or journaled as not measured: both are done); ``batches``: batches assessed in this run (a target-error capture; 0 otherwise);
    ``started_utc``/``ended_utc``: Unix times of the run. After a stop: ``detail`` the device's or
    library's message, ``axis`` the axis at fault, ``plan_index`` the plan sample under way,
    ``stops`` how each axis took the stop, ``lamp_off`` whether the lamp confirmed it is off (None:
    not asked, the run completed).
    """

    run: int
    status: RunStatus
    reason: str
    samples_planned: int
    samples_captured: int
    batches: int
    started_utc: float
    ended_utc: float
    detail: str = ""
    axis: str | None = None
    plan_index: int | None = None
    stops: tuple[AxisStop, ...] = field(default_factory=tuple)
    lamp_off: bool | None = None

    @property
    def stopped_early(self) -> bool:
        """True when the run ended on a fault, a refusal or an operator's stop (resumable)."""
        return not self.status.completed


LABEL_TEXT_FIELDS = ("operator", "sample_id", "lab", "lens", "lamp", "queue")


@dataclass(frozen=True)
class SessionLabel:
    """Who measured what, where (a lab's metadata; bluesky keeps the like in a run's ``md``).

    ``operator``, ``sample_id``, ``notes`` come from the command line (``capture --operator
    --sample-id --note``) or a queue file; ``lab``, ``lens``, ``lamp`` from the rig file's ``lab:``
    section; ``queue``: the queue file that measured the session (None: a single capture). Kept in
    the journal's meta (``Journal.label``), report.json and brdf.json; a resume keeps it and
    refuses one that contradicts it (``contradiction``).
    """

    operator: str | None = None
    sample_id: str | None = None
    notes: tuple[str, ...] = ()
    lab: str | None = None
    lens: str | None = None
    lamp: str | None = None
    queue: str | None = None

    def to_dict(self) -> dict:
        return {**{name: getattr(self, name) for name in LABEL_TEXT_FIELDS}, "notes": list(self.notes)}

    @classmethod
    def from_dict(cls, values: dict | None) -> "SessionLabel":
        """From ``to_dict`` (a journal from before labels: an empty label)."""
        values = values or {}
        return cls(**{name: values.get(name) for name in LABEL_TEXT_FIELDS}, notes=tuple(values.get("notes") or ()))

    def contradiction(self, given: "SessionLabel") -> tuple[str, object, object] | None:
        """(field, stored, given) of the first field ``given`` sets to another value than this
        stored label; None when it only repeats or adds to it (new notes are added)."""
        for name in LABEL_TEXT_FIELDS:
            stored, found = getattr(self, name), getattr(given, name)
            if found is not None and stored is not None and found != stored:
                return name, stored, found
            if found is not None and stored is None:
                return name, stored, found
        return None

    def merged(self, given: "SessionLabel") -> "SessionLabel":
        """This label with ``given``'s new notes appended (once each)."""
        notes = self.notes + tuple(n for n in given.notes if n not in self.notes)
        return SessionLabel(**{name: getattr(self, name) for name in LABEL_TEXT_FIELDS}, notes=notes)


@dataclass(frozen=True)
class SampleRecord:
    """One captured sample as journaled. Angles in degrees (cell lower edges), BRDF in 1/sr.

    ``rgb``/``sigma`` are (3,) tuples; ``joints`` maps axis name -> degrees actually reached;
    ``move_s``/``capture_s`` are the (simulated or real) seconds spent moving and capturing;
    ``started_utc``/``committed_utc`` are Unix times.
    """

    plan_index: int
    cell: int
    theta_h_deg: float
    theta_d_deg: float
    phi_d_deg: float
    rgb: tuple[float, float, float]
    sigma: tuple[float, float, float]
    snr: float
    joints: dict = field(default_factory=dict)
    exposures_s: tuple = ()
    frames_taken: int = 0
    frames_skipped: int = 0
    raw_paths: tuple = ()
    lamp_relative: float = 1.0
    move_s: float = 0.0
    capture_s: float = 0.0
    started_utc: float = 0.0
    committed_utc: float = 0.0
    status: str = "ok"


@dataclass(frozen=True)
class NotMeasuredRecord:
    """One plan sample the rig could not measure, as journaled (``calib.NotMeasured`` at its pose).

    ``reason`` a ``calib.NotMeasuredReason`` (a value this version does not know stays a str);
    ``snr`` (3,) the SNR reached per channel; ``min_snr`` the rig's minimum; ``longest_exposure_s``
    the longest exposure taken; ``lower_limit``, ``upper_limit`` (3,) the BRDF in 1/sr each channel
    lies between (too dark: 0 and an upper limit; saturated: a lower limit and infinity, None in
    ``to_dict``); the other fields as in SampleRecord (repeated, not inherited: a base class's
    fields would come first, and so would change the order of the journal's and reports' fields).
    """

    plan_index: int
    cell: int
    theta_h_deg: float
    theta_d_deg: float
    phi_d_deg: float
    reason: NotMeasuredReason
    snr: tuple[float, float, float]
    min_snr: float
    longest_exposure_s: float
    upper_limit: tuple[float, float, float]
    lower_limit: tuple[float, float, float] = (0.0, 0.0, 0.0)
    joints: dict = field(default_factory=dict)
    exposures_s: tuple = ()
    frames_taken: int = 0
    frames_skipped: int = 0
    raw_paths: tuple = ()
    lamp_relative: float = 1.0
    move_s: float = 0.0
    capture_s: float = 0.0
    started_utc: float = 0.0
    committed_utc: float = 0.0

    @property
    def best_snr(self) -> float:
        """The highest SNR reached over the channels."""
        return max(self.snr)

    def to_dict(self) -> dict:
        """JSON-safe form (report.json, events): the reason as its value."""
        return {**asdict(self), "reason": str(self.reason), "snr": list(self.snr),
                "upper_limit": json_limits(self.upper_limit),
                "lower_limit": list(self.lower_limit), "exposures_s": list(self.exposures_s),
                "raw_paths": list(self.raw_paths)}

    def why(self) -> str:
        """Why it was not measured and the bounds of its BRDF, in words (readers use the fields)."""
        return why_not_measured(self.reason, self.snr, self.min_snr, self.exposures_s or (self.longest_exposure_s,),
                                self.lower_limit, self.upper_limit)


def json_limits(values) -> list:
    """A limit triple for JSON: an infinite limit (none) as None."""
    return [v if math.isfinite(v) else None for v in values]


class SuspensionEnd(str, enum.Enum):
    """How a suspension ended (``Suspension.end``)."""

    RESUMED = "resumed"    # its conditions held clear for hold_clear_s (resume: auto)
    OPERATOR = "operator"  # they held clear and the operator resumed (resume: operator)
    STOPPED = "stopped"    # the run was stopped while suspended (Ctrl-C, SIGTERM, rig stop)
    GAVE_UP = "gave_up"    # a device stayed silent for give_up_s: the run ended as a fault

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Suspension:
    """One suspension of a run (the journal's ``suspensions`` table): ``reason`` a
    ``goniofrost.rig.suspenders.SuspendReason`` value, ``plan_index`` the sample it waited before,
    Unix times, ``waited_s`` session-clock seconds suspended and ``end`` (both None while it lasts)."""

    run: int
    reason: str
    plan_index: int | None
    started_utc: float
    ended_utc: float | None = None
    waited_s: float | None = None
    end: SuspensionEnd | None = None


@dataclass(frozen=True)
class Event:
    """What a run met or did, for the journal's events: ``kind`` an EventKind, ``message`` words
    for people, ``axis`` the axis concerned, ``data`` the fields readers read."""

    kind: EventKind
    message: str
    axis: str | None = None
    data: dict | None = None


@dataclass(frozen=True)
class DeviceMessages:
    """What the drivers logged since the last step (retries, failed stops): ``logging.LogRecord``s."""

    records: tuple


@dataclass(frozen=True)
class SafePoint:
    """The run may pause before ``step``: nothing is under way (a session's suspenders wait here,
    a simulated rig arms its drills). Handed to subscribers outside the journal's critical section."""

    step: object


@dataclass(frozen=True)
class StepStarting:
    """A plan step is about to be journaled and executed (a subscriber may wait here: a safe point)."""

    step: object


@dataclass(frozen=True)
class StepDone:
    """A step was executed: the ``step``, its ``result`` and the ``summary`` the journal keeps of it
    (``goniofrost.capture.steps.step_summary``, with the simulated state after a Commit or a
    SaveCalibration)."""

    step: object
    result: object
    summary: dict


@dataclass(frozen=True)
class StepFailed:
    """A run is being aborted during ``step`` (None: between steps): ``ended`` "failed" or
    "interrupted", ``detail`` the error's words. Every axis was already told to stop."""

    step: object
    ended: str
    detail: str


@dataclass(frozen=True)
class PlanEnded:
    """The plan ended, however (before the run's RunEnd): what was timed or shown may close."""
