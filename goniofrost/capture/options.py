"""How a capture runs its session, besides what it measures (``goniofrost.capture.runner.capture``):
when it stops (``StopRule``) and how it runs (``SessionOptions``)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

RERUN = "the same command with --resume"  # what a stopped capture tells the user to type next
DEFAULT_CONFIDENCE = 0.95


@dataclass(frozen=True)
class StopRule:
    """When a capture stops: once the material's log-relative MSE is at most ``target_error``
    with probability ``confidence`` (the calibrated bound of ``frost.confidence``; the plan needs
    batch_ends; ``goniofrost.capture.target``); ``target_error`` None: after the whole plan."""

    target_error: float | None = None
    confidence: float = DEFAULT_CONFIDENCE


@dataclass(frozen=True)
class ReusedCalibration:
    """Another session's journaled calibration ``record`` (a queue's sample before): only the
    white reference is measured again, and everything when its scale moved by more than
    ``drift_limit`` (relative; None: the session's default)."""

    record: dict
    drift_limit: float | None = None


@dataclass(frozen=True)
class SessionOptions:
    """``resume``: continue the session's journal; ``progress``: show a progress bar, labelled
    ``progress_desc`` (a queue: its position and the sample); ``label``: who measures what
    (``goniofrost.capture.lab.session_label``; default: the rig file's lab section alone; a resume
    keeps the journaled one, adds new notes and refuses another value); ``reuse``: a
    ReusedCalibration; ``rerun``: what the messages after a stop tell the user to type (a queue:
    the queue command itself, which has no --resume); ``extra_files``: the names of files the
    caller writes into the session folder after the capture (``capture --bsdf``: brdf.bsdf),
    checked with the capture's own before anything moves; ``compare``: what the report compares
    the session with (the demo's ``goniofrost.app.ground_truth.GroundTruth``: report.json's
    ``ground_truth`` and the preview's reference), None: nothing."""

    resume: bool = False
    progress: bool = True
    progress_desc: str = "capture"
    label: object | None = None
    reuse: ReusedCalibration | None = None
    rerun: str = RERUN
    extra_files: tuple[str | Path, ...] = ()
    compare: object | None = None
