"""The session plan is a list of steps, compared step by step without devices.

The plan is driven by a script that answers each step as a rig would (the joints reached, a
frame taken beforehand with the simulated camera), so the calibration frames and the adaptive
brackets appear in the list exactly as the plan asks for them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib import Bracket, CalibrationRecord, NotMeasured, NotMeasuredReason, SaturationError, validate_camera_section
from calib.holder import SAMPLE_MARKER_IDS
from calib.roi import expected_view
from drivers.rawfile import read_raw
from goniofrost.capture.sample_steps import sample_steps
from goniofrost.capture.session_steps import SessionSpec, remaining, session_steps
from goniofrost.capture.steps import (Commit, Expose, Frame, Home, LampOff, LampOn, Move, Phase, Reached,
                                      SaveCalibration, SetTarget, drive)
from sim.camera_bench import direction, rig_like

from frame_script import CAMERA_MODEL, LADDER, render_table

AXES = ("theta_i", "theta_o", "phi_o")    # the plan does not care what the joints mean
CAMERA = validate_camera_section({"kind": "sim", "exposures_s": LADDER, "target_snr": 100.0, "dark_frames": 1,
                                  **CAMERA_MODEL, "marker_tolerance_px": 200.0,   # scripted frames: one pose
                                  "flat_frames": 2, "white_reference": {"theta_i_deg": 0.0, "theta_o_deg": 30.0}},
                                 "test")
WHITE = {"theta_i": 0.0, "theta_o": 30.0, "phi_o": 180.0}
SAMPLES = [{"joints": {"theta_i": 0.0, "theta_o": 30.0 + 5 * i, "phi_o": 180.0 - 10 * i},
            "theta_h_deg": 10.0 + i, "theta_d_deg": 20.0 + i, "phi_d_deg": 90.0} for i in range(3)]


def pose_of(joints):
    return rig_like(direction(joints["theta_i"]), direction(joints["theta_o"], joints["phi_o"]))


SPEC = SessionSpec(SAMPLES, (101, 102, 103), AXES, CAMERA, WHITE, pose_of)
# a kept calibration: no dark, uniform flat, the scale of the simulated camera's white tile
# (rate per BRDF x cos theta_i: full well at 0.15 s for 1/pi in green)
RECORD = CalibrationRecord(LADDER, np.zeros((4, 144, 192), np.float32), np.ones((144, 192), np.float32),
                           np.array([12.0, 20.0, 15.0]), np.array([0.01, 0.01, 0.01]), {"reflectance": 0.95})


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """RawImages by (what the camera sees, ladder exposure): see frame_script."""
    return {key: read_raw(path) for key, path in render_table(tmp_path_factory.mktemp("frames")).items()}


class Script:
    """Answers each step as a rig would: the joints asked for, and the frame of what is in front
    of the camera (``sample`` shows ``sample_frames``) at the exposure asked for."""

    def __init__(self, frames, sample_frames: str = "sample") -> None:
        self.frames, self.sample_frames = frames, sample_frames
        self.lamp, self.target, self.steps = False, "sample", []

    def __call__(self, step):
        self.steps.append(step)
        if isinstance(step, Home):
            return Reached({a: 0.0 for a in step.axes}, 3.0, 1000.0)
        if isinstance(step, Move):
            return Reached(dict(step.joints), 1.5, 2000.0 + len(self.steps))
        if isinstance(step, (LampOn, LampOff)):
            self.lamp = isinstance(step, LampOn)
            return 1.0 if self.lamp else None
        if isinstance(step, SetTarget):
            self.target = step.target
        if isinstance(step, Expose):
            seen = "dark" if not self.lamp else self.sample_frames if self.target == "sample" else self.target
            lamp = 1.0 if self.lamp else 0.0
            return Frame(Path("/session") / step.file, step.exposure_s, self.frames[seen, step.exposure_s], lamp,
                         step.exposure_s, 0.01)
        if isinstance(step, SaveCalibration):
            return step.record
        return None


def _shown(steps):
    """The steps, with each Commit shown by its plan index (its record is checked on its own)."""
    return [("Commit", s.index) if isinstance(s, Commit) else s for s in steps]


def calibration_expected():
    """Dark frames with the lamp off, the flat at the longest exposure (it stays under saturation),
    the white card at the middle of the ladder (enough SNR at once), the record saved."""
    return [Phase("calibration"), LampOff(),
            *[Expose(t, f"calibration/dark_e{i}_0.dng") for i, t in enumerate(LADDER)], LampOn(),
            SetTarget("flat"), Expose(0.128, "calibration/flat_e3_0.dng"), Expose(0.128, "calibration/flat_e3_1.dng"),
            SetTarget("sample"), SetTarget("white"), Expose(0.032, "calibration/white_e2.dng"),
            SetTarget("sample"), SaveCalibration(None)]


def sample_moves(i):
    return Move(i, tuple((a, float(SAMPLES[i]["joints"][a])) for a in AXES))


def test_script_frames_are_what_the_expected_lists_assume(frames):
    assert np.percentile(frames["flat", 0.128].linear, 99.9) < CAMERA["saturation"]
    assert frames["bright", 0.032].saturated.any() and not frames["bright", 0.008].saturated.any()
    assert not frames["sample", 0.032].saturated.any() and not frames["white", 0.032].saturated.any()


def test_fresh_session_homes_calibrates_at_the_white_pose_then_moves_measures_and_commits_each_sample_in_plan_order(frames):
    script = Script(frames)
    drive(session_steps(SPEC), script)
    expected = [Home(AXES), LampOn(), Move(None, (("theta_i", 0.0), ("theta_o", 30.0), ("phi_o", 180.0))),
                *calibration_expected(), Phase("samples")]
    for i in range(3):
        expected += [sample_moves(i), Expose(0.032, f"raw/sample_{i:04d}_e2.dng", i), ("Commit", i)]
    assert _shown(script.steps) == expected + [LampOff(), Home(AXES)]   # lamp off, then back home

    # the calibration record came from those frames, at the white pose the Move reached
    [saved] = [s for s in script.steps if isinstance(s, SaveCalibration)]
    record = saved.record
    assert record.dark.shape == (4, 144, 192) and record.white["exposures_s"] == [0.032]
    assert record.white["w_o"] == pytest.approx(pose_of(WHITE)[1].tolist())
    np.testing.assert_array_equal(record.dark[1], frames["dark", 0.008].linear)

    # each Commit carries its sample: where the Move left the axes, what its frames gave
    commits = [s.record for s in script.steps if isinstance(s, Commit)]
    moves = [i for i, s in enumerate(script.steps) if isinstance(s, Move) and s.index is not None]
    for i, (r, at) in enumerate(zip(commits, moves)):
        assert (r.plan_index, r.cell, r.theta_h_deg, r.phi_d_deg) == (i, 101 + i, 10.0 + i, 90.0)
        assert r.joints == SAMPLES[i]["joints"] and r.move_s == 1.5 and r.started_utc == 2000.0 + at + 1
        assert r.exposures_s == (0.032,) and r.capture_s == 0.032 and r.frames_skipped == 3
        assert r.raw_paths == (f"/session/raw/sample_{i:04d}_e2.dng",) and r.committed_utc == 0.0
        assert r.status == "ok" and r.snr >= 100


def test_a_bright_sample_steps_down_and_the_next_sample_starts_from_its_value(frames):
    script = Script(frames, sample_frames="bright")
    drive(session_steps(SPEC, done={2}), script)
    samples = script.steps[script.steps.index(Phase("samples")):]
    # the white-like guess saturates the first sample: one exposure shorter; the second starts there
    assert _shown(samples) == [Phase("samples"),
                               sample_moves(0), Expose(0.032, "raw/sample_0000_e2.dng", 0),
                               Expose(0.008, "raw/sample_0000_e1.dng", 0), ("Commit", 0),
                               sample_moves(1), Expose(0.008, "raw/sample_0001_e1.dng", 1), ("Commit", 1),
                               LampOff(), Home(AXES)]


def test_resumed_session_skips_journaled_samples_and_a_kept_calibration(frames):
    script = Script(frames)
    drive(session_steps(SPEC, done={0, 2}, calibration=RECORD), script)
    assert _shown(script.steps) == [Home(AXES), LampOn(), Phase("samples"), sample_moves(1),
                                    Expose(0.032, "raw/sample_0001_e2.dng", 1), ("Commit", 1), LampOff(),
                                    Home(AXES)]
    assert remaining(3, {0, 2}) == [1]


def test_a_finished_session_touches_no_device():
    assert list(session_steps(SPEC, done={0, 1, 2})) == []


# ----- the adaptive bracket, driven by a scripted frame sequence ----------------------------

def bracket_of(sequence, expected=None, **settings):
    """The Expose steps a sample's bracket yields when the camera returns ``sequence`` in order."""
    asked, script = [], list(sequence)

    def camera(step):
        asked.append(step)
        return Frame(Path(step.file), step.exposure_s, script.pop(0), 1.0, step.exposure_s, 0.0)

    m = drive(sample_steps({**CAMERA, **settings}, RECORD, pose_of(WHITE), 7, expected), camera)
    assert script == [], "the bracket stopped before using every scripted frame"
    return [(s.exposure_s, s.file) for s in asked], m


def test_a_saturated_frame_asks_for_the_next_shorter_exposure(frames):
    asked, m = bracket_of([frames["bright", 0.032], frames["bright", 0.008]])
    assert asked == [(0.032, "raw/sample_0007_e2.dng"), (0.008, "raw/sample_0007_e1.dng")]
    assert m.exposures_s == [0.008, 0.032] and m.frames_skipped == 2


def test_a_low_snr_frame_asks_for_longer_exposures_until_the_target_or_saturation(frames):
    # a dark sample before (BRDF 0.06/pi): the first exposure is the longest, and the last
    asked, m = bracket_of([frames["sample", 0.032]], expected=np.full(3, 0.06), target_snr=1e6, min_snr=1.0)
    assert asked == [(0.128, "raw/sample_0007_e3.dng")] and m.flags == ["low-snr"]
    # a bright sample before: the shortest first; no SNR reaches 1e6, so each longer frame is asked
    # for while the next is predicted not to saturate ...
    asked, m = bracket_of([frames["sample", 0.002], frames["sample", 0.008], frames["sample", 0.032],
                           frames["sample", 0.128]], expected=np.full(3, 10.0), target_snr=1e6, min_snr=1.0)
    assert [t for t, _ in asked] == [0.002, 0.008, 0.032, 0.128] and m.flags == ["low-snr"]
    # ... so the 8x brighter sample stops after 0.032 s: 0.128 s would saturate every channel, and
    # 0.032 s saturates the green channel's pixels (left out of the merge) but not red and blue
    asked, m = bracket_of([frames["bright", 0.002], frames["bright", 0.008], frames["bright", 0.032]],
                          expected=np.full(3, 10.0), target_snr=1e6, min_snr=1.0)
    assert [t for t, _ in asked] == [0.002, 0.008, 0.032]
    bright = frames["bright", 0.032]
    green = bright.channels == 1
    assert bright.saturated[green].mean() > 2 * bright.saturated[~green].mean()
    # with a reachable target the bracket stops as soon as the SNR is there (0.002 s: SNR 140)
    asked, m = bracket_of([frames["sample", 0.002], frames["sample", 0.008]], expected=np.full(3, 10.0),
                          target_snr=200.0)
    assert [t for t, _ in asked] == [0.002, 0.008] and m.flags == [] and np.all(m.snr >= 200)


def test_frames_without_markers_search_the_nearest_exposures_then_the_patch_is_found(frames):
    asked, m = bracket_of([frames["dark", 0.032], frames["dark", 0.128], frames["sample", 0.008]])
    # no markers at the start (index 2): the nearest untaken exposures, longer first (not saturated)
    assert [t for t, _ in asked] == [0.032, 0.128, 0.008]
    assert m.exposures_s == [0.008, 0.032, 0.128]


def test_a_sample_saturated_at_the_shortest_exposure_is_not_measured_but_a_white_reference_is_an_error(frames):
    # a sample: recorded as not measured after the shortest exposure, with a lower limit of its BRDF
    asked, m = bracket_of([frames["bright", 0.128]], expected=np.full(3, 1e3))
    assert asked == [(0.002, "raw/sample_0007_e0.dng")]
    assert isinstance(m, NotMeasured) and m.reason is NotMeasuredReason.SATURATED and m.exposures_s == [0.002]
    assert np.all(np.isinf(m.upper_limit)) and np.all(m.lower_limit > 0)
    # a reference's bracket (the white reference's, the holder cards' snapshots: Bracket's default)
    # raises instead: the session cannot go on without it
    bracket = Bracket(LADDER, CAMERA, RECORD, SAMPLE_MARKER_IDS, "white reference",
                      view=expected_view(CAMERA, pose_of(WHITE), SAMPLE_MARKER_IDS, 1.0))
    with pytest.raises(SaturationError, match=r"white reference: \d+ of \d+ sample pixels saturate even at the "
                                              r"shortest exposure 0.002 s"):
        bracket.add(0, frames["bright", 0.128], 1.0, Path("white_e0.dng"))


# ----- a capture with a target error: batches, assessments, stop -------------------------------
def target_spec(predicted_after: dict, target: float = 0.05, batch_ends=(1, 2, 3)):
    """SPEC measured in batches; the error bound after k samples is ``predicted_after[k]``."""
    import dataclasses

    from goniofrost.frost.confidence import ErrorBound

    # the bound after k samples is predicted_after[k], its median estimate a tenth of it
    return dataclasses.replace(SPEC, target=target, batch_ends=tuple(batch_ends), confidence=0.95,
                               assess=lambda records: ErrorBound(predicted_after[len(records)] / 10,
                                                                 predicted_after[len(records)], 0.95))


def assess_step(batch, samples, bound, decision, target=0.05):
    """The Assess step target_spec's bounds give."""
    from goniofrost.capture.steps import Assess

    return Assess(batch, samples, bound / 10, target, decision, bound, 0.95, ())


def test_target_session_stops_after_the_first_batch_whose_predicted_error_is_at_most_the_target(frames):
    from goniofrost.capture.steps import Assess

    script = Script(frames)
    drive(session_steps(target_spec({1: 0.2, 2: 0.04, 3: 0.01}), calibration=RECORD), script)
    assert _shown(script.steps) == [
        Home(AXES), LampOn(), Phase("samples"),
        sample_moves(0), Expose(0.032, "raw/sample_0000_e2.dng", 0), ("Commit", 0), assess_step(0, 1, 0.2, "continue"),
        sample_moves(1), Expose(0.032, "raw/sample_0001_e2.dng", 1), ("Commit", 1), assess_step(1, 2, 0.04, "target reached"),
        LampOff(), Home(AXES)]


def test_target_session_uses_up_the_plan_when_the_target_is_never_met(frames):
    from goniofrost.capture.steps import Assess

    script = Script(frames)
    drive(session_steps(target_spec({1: 0.2, 2: 0.1, 3: 0.09}, batch_ends=(2, 3)), calibration=RECORD), script)
    assessed = [s for s in script.steps if isinstance(s, Assess)]
    assert assessed == [assess_step(0, 2, 0.1, "continue"), assess_step(1, 3, 0.09, "plan used up")]
    assert [s.index for s in script.steps if isinstance(s, Commit)] == [0, 1, 2] and script.steps[-2:] == [LampOff(), Home(AXES)]


def test_a_resumed_target_session_replays_the_journaled_batches_first(frames):
    """Sample 0 journaled (batch 1 done), sample 1 not: batch 1 is assessed again before any device
    step, then batch 2 is captured; a session that had stopped yields no device step at all."""
    from goniofrost.capture.steps import Assess

    done = []

    def journaled(script_frames):  # a first run of batch 1, recorded as the journal would hold it
        script = Script(script_frames)
        drive(session_steps(target_spec({1: 0.2, 2: 0.2, 3: 0.2}), calibration=RECORD), script)
        return [s.record for s in script.steps if isinstance(s, Commit)][:1]

    records = journaled(frames)
    script = Script(frames)
    drive(session_steps(target_spec({1: 0.2, 2: 0.01, 3: 0.0}), done={0}, calibration=RECORD, records=records), script)
    assert _shown(script.steps)[:2] == [assess_step(0, 1, 0.2, "continue"), Home(AXES)]
    assert _shown(script.steps)[-4:] == [("Commit", 1), assess_step(1, 2, 0.01, "target reached"), LampOff(), Home(AXES)]
    stopped = target_spec({1: 0.01, 2: 0.0, 3: 0.0})
    assert list(session_steps(stopped, done={0}, records=records)) == [assess_step(0, 1, 0.01, "target reached")]


def test_samples_out_of_the_model_keep_the_capture_measuring_while_the_plan_allows(frames):
    """A bound far below the target, but the samples unlike every training material: the capture
    never stops on it and measures the whole plan."""
    import dataclasses

    from goniofrost.capture.steps import Assess
    from goniofrost.frost.confidence import ErrorBound

    spec = dataclasses.replace(target_spec({}), assess=lambda records: ErrorBound(0.001, 0.01, 0.95, ("z2",)))
    script = Script(frames)
    drive(session_steps(spec, calibration=RECORD), script)
    decisions = [(s.samples, s.decision, s.out_of_model) for s in script.steps if isinstance(s, Assess)]
    assert decisions == [(1, "continue", ("z2",)), (2, "continue", ("z2",)), (3, "plan used up", ("z2",))]
    assert [s.index for s in script.steps if isinstance(s, Commit)] == [0, 1, 2]


def test_a_target_session_leaves_a_sample_journaled_not_measured_out_of_the_capture_and_the_assessments(frames):
    """Sample 0 journaled as not measured (too dark): nothing of it is taken again, batch 1 (only
    sample 0) has no measured sample and is not assessed, batch 2 is assessed on sample 1 alone; the
    report's replay from the journal (capture.target.history) makes the same decisions."""
    import dataclasses

    from goniofrost.capture.steps import Assess
    from goniofrost.capture.target import finished, history

    spec = target_spec({1: 0.01})
    script = Script(frames)
    drive(session_steps(spec, done={0}, calibration=RECORD, not_measured=[0]), script)
    assert all(getattr(s, "index", None) != 0 for s in script.steps)
    [assessed] = [s for s in script.steps if isinstance(s, Assess)]
    assert assessed == dataclasses.replace(assess_step(1, 2, 0.01, "target reached"), not_measured=1)
    records = [s.record for s in script.steps if isinstance(s, Commit)]
    assert [r.plan_index for r in records] == [1]
    replay = history(spec.assess, spec.batch_ends, spec.target, records, not_measured=[0])
    assert replay == [dataclasses.asdict(assessed)]
    assert finished(spec.assess, spec.batch_ends, spec.target, records, not_measured=[0])
    assert not finished(spec.assess, spec.batch_ends, spec.target, [], not_measured=[0])
