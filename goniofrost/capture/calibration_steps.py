"""The calibration as steps: dark frames, flat field and white reference, each frame one step.

``calibration_steps`` yields, in order: the lamp off and ``dark_frames`` frames per ladder
exposure, the lamp on; the ``flat`` target and frames from the longest exposure down until one
stays under saturation, then ``flat_frames`` at that exposure; the ``white`` target and an
adaptive bracket of it; the ``sample`` target back; and a SaveCalibration of the record. The
computations on the frames are ``calib``'s (pure); this module only says which frame comes next.
"""
from __future__ import annotations

import numpy as np

from calib import (Bracket, CalibrationRecord, SaturationError, dark_map, flat_field, flat_usable,
                   nominal_white_pose, start_index, white_scale)
from calib.holder import WHITE_MARKER_IDS
from calib.references import unit
from calib.roi import expected_view
from goniofrost.capture.sample_steps import bracket_steps, frame_file
from goniofrost.capture.steps import Expose, LampOff, LampOn, Phase, SaveCalibration, SetTarget, WhiteCheck

CALIBRATION_DIR = "calibration"


def calibration_steps(settings: dict, white_pose=None, folder: str = CALIBRATION_DIR, arm_side: float = 1.0):
    """Yield every step of a calibration; return the saved CalibrationRecord.

    ``settings``: the validated camera section; ``white_pose``: the actual (w_i, w_o), each (3,),
    at which the white tile is held (default: the settings' nominal ``white_reference`` angles);
    ``folder``: where frames and arrays go, relative to the session folder; ``arm_side``: see
    ``sample_steps``. Leaves the lamp on and the ``sample`` target in place.
    """
    ladder = settings["exposures_s"]
    yield Phase("calibration")
    dark = yield from dark_steps(ladder, settings["dark_frames"], folder)
    flat = yield from flat_steps(ladder, settings, dark, folder)
    record = CalibrationRecord(ladder, dark, flat, np.ones(3), np.zeros(3))
    white_pose = nominal_white_pose(settings) if white_pose is None else white_pose
    yield from white_steps(record, settings, white_pose, folder, arm_side)
    return (yield SaveCalibration(record, folder))


def white_check_steps(settings: dict, kept: CalibrationRecord, white_pose, drift_limit: float,
                      folder: str = CALIBRATION_DIR, arm_side: float = 1.0):
    """Re-measure the white reference with ``kept``'s dark maps and flat field (the calibration of
    the queue's sample before); return the saved record, or None when the white scale moved by
    more than ``drift_limit`` (relative, any channel: the lamp drifted) and a full calibration
    is due. Needs the lamp on and the white pose reached; leaves the ``sample`` target in place."""
    yield Phase("white_reference")
    record = CalibrationRecord(list(kept.exposures_s), kept.dark, kept.flat, np.ones(3), np.zeros(3))
    yield from white_steps(record, settings, white_pose, folder, arm_side)
    drift = white_drift(kept.scale, record.scale)
    decision = "reuse" if drift <= drift_limit else "recalibrate"
    yield WhiteCheck(drift, float(drift_limit), decision)
    if decision != "reuse":
        return None
    return (yield SaveCalibration(record, folder))


def white_drift(before, after) -> float:
    """The largest relative change |after / before - 1| over the channels of two white scales (3,)."""
    before, after = np.asarray(before, dtype=np.float64), np.asarray(after, dtype=np.float64)
    return float(np.max(np.abs(after / before - 1.0)))


def dark_steps(ladder: list, n_frames: int, folder: str):
    """Lamp off, ``n_frames`` frames per exposure, lamp on; return the dark maps (n, H, W) float32."""
    yield LampOff()
    maps = []
    for i, t in enumerate(ladder):
        raws = []
        for k in range(n_frames):
            raws.append((yield Expose(t, frame_file(folder, f"dark_e{i}_{k}.dng"))).raw)
        maps.append(dark_map(raws))
    yield LampOn()
    return np.stack(maps)


def flat_steps(ladder: list, settings: dict, dark: np.ndarray, folder: str):
    """The ``flat`` target at the longest exposure under saturation; return the gain (H, W) float32."""
    yield SetTarget("flat")
    for i in reversed(range(len(ladder))):
        first = (yield Expose(ladder[i], frame_file(folder, f"flat_e{i}_0.dng"))).raw
        if flat_usable(first, settings):
            break
    else:
        raise SaturationError(f"flat field: saturated even at {ladder[0]} s")
    raws = [first]
    for k in range(1, settings["flat_frames"]):
        raws.append((yield Expose(ladder[i], frame_file(folder, f"flat_e{i}_{k}.dng"))).raw)
    yield SetTarget("sample")
    return flat_field(raws, dark[i], ladder[i])


def white_steps(record: CalibrationRecord, settings: dict, white_pose, folder: str, arm_side: float = 1.0):
    """Bracket the ``white`` target at ``white_pose``; set the record's absolute scale from it."""
    w_i = unit(white_pose[0], "white reference w_i")
    ladder = settings["exposures_s"]
    yield SetTarget("white")
    bracket = Bracket(ladder, settings, record, WHITE_MARKER_IDS, "white reference",
                      view=expected_view(settings, white_pose, WHITE_MARKER_IDS, arm_side))
    yield from bracket_steps(bracket, start_index(ladder, settings, record, None, w_i), folder, "white")
    yield SetTarget("sample")
    mean, se = bracket.stats()
    record.scale, record.scale_sigma, record.white = white_scale(mean, se, white_pose, settings, bracket.exposures_s)
