"""A sample's measurement as steps: one Expose per exposure the adaptive bracket asks for.

``sample_steps`` yields the bracket's frames at the pose just reached and returns the calibrated
``calib.SampleMeasurement`` (or a ``calib.NotMeasured`` record: too dark or too bright for the ladder); ``bracket_steps`` is the loop it shares with the white reference:
expose, hand the frame to the bracket rule (``calib.Bracket.add``), expose what it asks next.
"""
from __future__ import annotations

from pathlib import PurePosixPath

from calib import Bracket, check_record, light_direction, sample_measurement, start_index
from calib.holder import SAMPLE_MARKER_IDS
from calib.roi import expected_view
from goniofrost.capture.steps import Expose

RAW_DIR = "raw"


def sample_steps(settings: dict, record, pose, index: int, expected=None, folder: str = RAW_DIR,
                 arm_side: float = 1.0):
    """Yield the frames of plan sample ``index``; return its SampleMeasurement, or a NotMeasured
    record when no channel reaches ``min_snr`` even with the ladder's longest exposure or patch
    pixels saturate even at its shortest.

    ``settings``: the validated camera section; ``record``: the CalibrationRecord; ``pose``:
    (w_i, w_o), each (3,), actually reached; ``expected``: (3,) BRDF in 1/sr the sample probably
    has (the previous sample's), which picks the first exposure; ``folder``: where the frames go,
    relative to the session folder; ``arm_side``: +1 when the camera arm works counter-clockwise
    of the light (``planner.kinematics.arm_side``), for the camera model's prediction of the patch.
    """
    ladder = settings["exposures_s"]
    check_record(record, ladder)
    w_i = light_direction(pose[0], index)
    bracket = Bracket(ladder, settings, record, SAMPLE_MARKER_IDS, f"sample {index}",
                      view=expected_view(settings, pose, SAMPLE_MARKER_IDS, arm_side), record_saturation=True)
    first = start_index(ladder, settings, record, expected, w_i)
    seconds, wall_s = yield from bracket_steps(bracket, first, folder, f"sample_{index:04d}", index)
    return sample_measurement(index, bracket, w_i, capture_seconds=wall_s, clock_seconds=seconds)


def bracket_steps(bracket: Bracket, first: int, folder: str, stem: str, index: int | None = None):
    """Expose ladder index ``first``, then whatever ``bracket`` asks for next, into
    FOLDER/STEM_e<i>.dng; return (session-clock seconds, real seconds) spent exposing."""
    i, seconds, wall_s = first, 0.0, 0.0
    while i is not None:
        frame = yield Expose(bracket.ladder[i], frame_file(folder, f"{stem}_e{i}.dng"), index)
        seconds, wall_s = seconds + frame.seconds, wall_s + frame.wall_s
        i = bracket.add(i, frame.raw, frame.lamp_relative, frame.path, frame.exposure_s)
    return seconds, wall_s


def frame_file(folder: str, name: str) -> str:
    """A frame's file relative to the session folder (``folder`` may be empty)."""
    return str(PurePosixPath(folder, name))
