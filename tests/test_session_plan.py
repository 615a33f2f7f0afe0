"""The session plan is a pure list of steps: compared step by step, without devices."""
from __future__ import annotations

from goniofrost.capture.steps import Calibrate, Commit, Home, LampOff, LampOn, Measure, Move, remaining, session_steps

AXES = ("camera_arm", "sample_yaw", "sample_tilt")
SAMPLES = [{"joints": {"camera_arm": 30.0 + i, "sample_yaw": -i, "sample_tilt": 2.5 * i}} for i in range(3)]


def test_fresh_session_homes_calibrates_at_the_white_pose_then_moves_measures_and_commits_each_sample_in_plan_order():
    white = {"camera_arm": 30.0, "sample_yaw": 0.0, "sample_tilt": 0.0}
    steps = list(session_steps(SAMPLES, AXES, white_joints=white))
    expected = [Home(AXES), LampOn(), Move(None, (("camera_arm", 30.0), ("sample_yaw", 0.0), ("sample_tilt", 0.0))),
                Calibrate()]
    for i in range(3):
        expected += [Move(i, (("camera_arm", 30.0 + i), ("sample_yaw", float(-i)), ("sample_tilt", 2.5 * i))),
                     Measure(i), Commit(i)]
    assert steps == expected + [LampOff()]


def test_resumed_session_skips_journaled_samples_and_a_kept_calibration():
    steps = list(session_steps(SAMPLES, AXES, done={0, 2}, calibrated=True))
    assert steps == [Home(AXES), LampOn(), Move(1, (("camera_arm", 31.0), ("sample_yaw", -1.0), ("sample_tilt", 2.5))),
                     Measure(1), Commit(1), LampOff()]
    assert remaining(3, {0, 2}) == [1]


def test_a_finished_session_touches_no_device():
    assert list(session_steps(SAMPLES, AXES, done={0, 1, 2}, calibrated=False)) == []
