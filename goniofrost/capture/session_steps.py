"""The capture session as a plan: every device step in order, with no side effects.

``session_steps`` yields: home, lamp on; unless a calibration is kept, the move to the white
reference pose and the calibration (``calibration_steps``: dark frames, flat field, white
reference, each frame a step); then per remaining sample: move, its bracket of exposures
(``sample_steps``), commit; finally lamp off. Each Move's result (the joints reached) gives the
pose the next steps use, and the Commit carries the whole sample record, so nothing passes
through the engine between steps. Samples already in the journal are skipped, so a resumed
session never repeats one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from goniofrost.capture.calibration_steps import calibration_steps
from goniofrost.capture.journal import SampleRecord
from goniofrost.capture.sample_steps import sample_steps
from goniofrost.capture.steps import Commit, Home, LampOff, LampOn, Move, Phase, Reached


@dataclass(frozen=True)
class SessionSpec:
    """What the session plan needs to know.

    ``samples``: the plan's samples in capture order, each with ``joints`` {axis: deg} and its cell's
    ``theta_h_deg``, ``theta_d_deg``, ``phi_d_deg``; ``cells`` (n,) their flat grid cells;
    ``axes``: axis names in joint order; ``camera``: the validated ``camera:`` section;
    ``white_joints``: the pose {axis: deg} showing the white reference tile (needed unless a
    calibration is kept); ``pose_of(joints)`` -> (w_i, w_o), each (3,): forward kinematics.
    """

    samples: list
    cells: tuple
    axes: tuple
    camera: Mapping
    white_joints: Mapping | None
    pose_of: Callable

    @classmethod
    def from_inputs(cls, inputs) -> "SessionSpec":
        """From checked ``goniofrost.capture.inputs.SessionInputs``."""
        from calib import validate_camera_section
        from planner.kinematics import forward

        rig = inputs.rig
        return cls(inputs.samples, tuple(int(c) for c in inputs.cells), tuple(rig.joint_names),
                   validate_camera_section(rig.camera, rig.source), inputs.white_joints,
                   lambda joints: forward(rig, joints))


def session_steps(spec: SessionSpec, done: Iterable[int] = (), calibration=None,
                  measured: Mapping[int, Sequence[float]] | None = None):
    """Yield the steps of a capture session (send each step's result back).

    ``done``: plan indices already journaled; ``calibration``: a journaled CalibrationRecord to keep
    (a resumed session), or None to calibrate; ``measured``: {plan index: (3,) BRDF} of journaled
    samples. Each sample's bracket starts from what the plan sample before it measured (in this
    run or, resumed, in the journal), so a resumed session takes the frames one run would have.
    A session with nothing left to capture yields no step at all.
    """
    todo = remaining(len(spec.samples), done)
    if not todo:
        return  # nothing left to capture: touch no device
    yield Home(spec.axes)
    yield LampOn()
    if calibration is None:
        white = yield Move(None, joint_targets(spec.white_joints, spec.axes))
        calibration = yield from calibration_steps(spec.camera, spec.pose_of(white.joints))
    yield Phase("samples")
    measured = {i: np.asarray(rgb, dtype=np.float64) for i, rgb in (measured or {}).items()}
    for index in todo:
        reached = yield Move(index, joint_targets(spec.samples[index]["joints"], spec.axes))
        previous = measured.get(index - 1)  # its BRDF picks this bracket's first exposure
        expected = None if previous is None else np.maximum(previous, 1e-6)
        m = yield from sample_steps(spec.camera, calibration, spec.pose_of(reached.joints), index, expected)
        measured[index] = np.asarray(m.rgb, dtype=np.float64)
        yield Commit(sample_record(spec, index, reached, m))
    yield LampOff()


def remaining(n_samples: int, done: Iterable[int]) -> list[int]:
    """Plan indices still to capture, in plan order."""
    done = set(done)
    return [i for i in range(n_samples) if i not in done]


def joint_targets(joints: Mapping, axes: tuple) -> tuple[tuple[str, float], ...]:
    """(axis, degrees) pairs in joint order."""
    return tuple((name, float(joints[name])) for name in axes)


def sample_record(spec: SessionSpec, index: int, reached: Reached, m) -> SampleRecord:
    """The journal record of plan sample ``index`` measured as ``m`` (calib.SampleMeasurement) at
    ``reached``; ``committed_utc`` is left for the engine to stamp."""
    sample = spec.samples[index]
    return SampleRecord(
        plan_index=index, cell=int(spec.cells[index]), theta_h_deg=float(sample["theta_h_deg"]),
        theta_d_deg=float(sample["theta_d_deg"]), phi_d_deg=float(sample["phi_d_deg"]),
        rgb=_triple(m.rgb), sigma=_triple(m.sigma), snr=float(np.min(m.snr)), joints=dict(reached.joints),
        exposures_s=tuple(map(float, m.exposures_s)), frames_taken=int(m.frames_taken),
        frames_skipped=int(m.frames_skipped), raw_paths=tuple(str(p) for p in m.raw_paths),
        lamp_relative=float(m.lamp_relative), move_s=float(reached.seconds), capture_s=float(m.clock_seconds),
        started_utc=float(reached.started_utc), status=",".join(m.flags) or "ok")


def _triple(values) -> tuple[float, float, float]:
    a = np.asarray(values, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))
