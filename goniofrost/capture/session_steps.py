"""The capture session as a plan: every device step in order, with no side effects.

``session_steps`` yields: home, lamp on; the calibration (``calibration_steps``) unless one is
kept; per remaining sample a move, its exposure bracket (``sample_steps``) and a commit (a
``SampleRecord`` or ``NotMeasuredRecord``); then lamp off and home. Journaled samples are skipped,
so a resume never repeats one. With a target error (``SessionSpec.target``) the samples go batch
by batch (``batch_ends``) and an ``Assess`` step after each carries the bound and the decision
(``goniofrost.capture.target``); journaled batches are assessed again first, so a resumed session
makes the same decisions.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from calib import NotMeasured
from goniofrost.capture.calibration_steps import calibration_steps, white_check_steps
from goniofrost.capture.records import NotMeasuredRecord, SampleRecord
from goniofrost.capture.sample_steps import sample_steps
from goniofrost.capture.steps import Assess, Commit, Home, LampOff, LampOn, Move, Phase, Reached


@dataclass(frozen=True)
class SessionSpec:
    """What the session plan needs to know.

    ``samples``: the plan's samples in capture order, each with ``joints`` {axis: deg} and its cell's
    ``theta_h_deg``, ``theta_d_deg``, ``phi_d_deg``; ``cells`` (n,) their flat grid cells;
    ``axes``: axis names in joint order; ``camera``: the validated ``camera:`` section;
    ``white_joints``: the pose {axis: deg} showing the white reference tile (needed unless a
    calibration is kept); ``pose_of(joints)`` -> (w_i, w_o), each (3,): forward kinematics (with
    the rig's alignment); ``arm_side``: +1 when the arm works counter-clockwise of the light.
    With a target error: ``target`` (log-relative MSE), ``confidence``, ``batch_ends`` (cumulative samples per
    batch, the last = all) and ``assess(records) -> frost.confidence.ErrorBound`` at the
    session's confidence; otherwise None, (), None.
    ``drift_limit``: with a calibration to reuse (a queue), the relative change of the white scale
    beyond which the session calibrates again in full. ``suspenders``: what pauses the run between
    samples until it clears (``goniofrost.capture.suspension``).
    """

    samples: list
    cells: tuple
    axes: tuple
    camera: Mapping
    white_joints: Mapping | None
    pose_of: Callable
    arm_side: float = 1.0
    target: float | None = None
    batch_ends: tuple = ()
    assess: Callable | None = None
    confidence: float | None = None
    drift_limit: float = 0.05
    suspenders: object = None  # goniofrost.rig.suspenders.Suspenders of the rig file, or None

    @classmethod
    def from_inputs(cls, inputs, target_error: float | None = None, confidence: float = 0.95) -> "SessionSpec":
        """From checked ``goniofrost.capture.inputs.SessionInputs`` (and the capture's target error
        and confidence)."""
        from calib import validate_camera_section
        from planner.kinematics import arm_side, forward

        from goniofrost.capture.target import make_assessor

        rig = inputs.rig
        target = {} if target_error is None else {
            "target": float(target_error), "batch_ends": tuple(int(e) for e in inputs.plan["batch_ends"]),
            "assess": make_assessor(inputs.model, inputs.positions, confidence, inputs.scene, inputs.sentinel),
            "confidence": float(confidence)}
        from goniofrost.rig.suspenders import Suspenders

        return cls(inputs.samples, tuple(int(c) for c in inputs.cells), tuple(rig.joint_names),
                   validate_camera_section(rig.camera, rig.source), inputs.white_joints,
                   lambda joints: forward(rig, joints), arm_side(rig),
                   suspenders=Suspenders.from_section(getattr(rig, "suspenders", None)), **target)


def session_steps(spec: SessionSpec, done: Iterable[int] = (), calibration=None,
                  measured: Mapping[int, Sequence[float]] | None = None, records=(), reuse=None,
                  not_measured: Iterable[int] = ()):
    """Yield the steps of a capture session (send each step's result back).

    ``done``: plan indices already journaled (measured or not); ``calibration``: a journaled
    CalibrationRecord to keep (a resumed session), or None to calibrate; ``measured``: {plan index: (3,) BRDF} of journaled
    samples. Each sample's bracket starts from what the plan sample before it measured (in this
    run or, resumed, in the journal), so a resumed session takes the frames one run would have.
    ``records``: the journaled SampleRecords (with a target error: its assessments need their
    values). A session with nothing left to capture yields no device step at all. ``reuse``: a
    CalibrationRecord of another session (a queue's sample before) whose darks and flat field are
    kept, when no ``calibration`` is: only the white reference is measured again
    (``white_check_steps``), and everything when it drifted past ``spec.drift_limit``.
    ``not_measured``: plan indices journaled as not measured (with a target error: their batches
    are complete without a value for them).
    """
    if spec.target is not None:
        yield from _target_session(spec, calibration, records, measured, reuse, set(not_measured))
        return
    todo = remaining(len(spec.samples), done)
    if not todo:
        return  # nothing left to capture: touch no device
    calibration = yield from _start(spec, calibration, reuse)
    yield from _capture(spec, calibration, todo, _as_arrays(measured))
    yield from _finish(spec)


def _finish(spec: SessionSpec):
    """Lamp off, then home: the return home the plan's ``return_home_s`` counts."""
    yield LampOff()
    yield Home(spec.axes)


def _start(spec: SessionSpec, calibration, reuse=None):
    """Home, lamp on, calibrate unless a calibration is kept (only the white reference when one
    is reused and the lamp has not drifted); return the calibration."""
    yield Home(spec.axes)
    yield LampOn()
    if calibration is None:
        white = yield Move(None, joint_targets(spec.white_joints, spec.axes))
        pose = spec.pose_of(white.joints)
        if reuse is not None:
            calibration = yield from white_check_steps(spec.camera, reuse, pose, spec.drift_limit,
                                                       arm_side=spec.arm_side)
        if calibration is None:
            calibration = yield from calibration_steps(spec.camera, pose, arm_side=spec.arm_side)
    yield Phase("samples")
    return calibration


def _capture(spec: SessionSpec, calibration, todo, measured: dict, records: dict | None = None,
             skipped: set | None = None):
    """Move, measure and commit each plan sample of ``todo``; their BRDFs go into ``measured``
    ({plan index: (3,)}; the one before a sample picks its bracket's first exposure) and their
    records into ``records``. A sample too dark or too bright to measure is committed as not measured (its index
    into ``skipped``) and the capture goes on: the next bracket starts as the first does."""
    for index in todo:
        reached = yield Move(index, joint_targets(spec.samples[index]["joints"], spec.axes))
        previous = measured.get(index - 1)  # its BRDF picks this bracket's first exposure
        expected = None if previous is None else np.maximum(previous, 1e-6)
        m = yield from sample_steps(spec.camera, calibration, spec.pose_of(reached.joints), index, expected,
                                    arm_side=spec.arm_side)
        if isinstance(m, NotMeasured):
            if skipped is not None:
                skipped.add(index)
            yield Commit(not_measured_record(spec, index, reached, m))
            continue
        measured[index] = np.asarray(m.rgb, dtype=np.float64)
        record = sample_record(spec, index, reached, m)
        if records is not None:
            records[index] = record
        yield Commit(record)


def _target_session(spec: SessionSpec, calibration, records, measured, reuse=None, skipped: set | None = None):
    """Batch by batch until the error is at most the target with the session's confidence (see
    module doc)."""
    from goniofrost.capture.target import CONTINUE, assessment

    by_index, skipped = {r.plan_index: r for r in records}, set(skipped or ())
    measured = _as_arrays(measured) | {i: np.asarray(r.rgb, dtype=np.float64) for i, r in by_index.items()}
    started, n, done = False, len(spec.samples), []
    for batch, end in enumerate(spec.batch_ends):
        todo = [i for i in range(end) if i not in by_index and i not in skipped]
        if todo:
            if not started:
                calibration = yield from _start(spec, calibration, reuse)
                started = True
            yield from _capture(spec, calibration, todo, measured, by_index, skipped)
        batch_records = [by_index[i] for i in range(end) if i in by_index]
        if not batch_records:
            continue   # nothing measured yet: nothing to assess
        result = assessment(spec.assess, batch, end, n, spec.target, batch_records, end - len(batch_records), done)
        done.append(result)
        yield Assess(**result)
        if result["decision"] != CONTINUE:
            break
    if started:
        yield from _finish(spec)


def _as_arrays(measured) -> dict:
    return {i: np.asarray(rgb, dtype=np.float64) for i, rgb in (measured or {}).items()}


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


def not_measured_record(spec: SessionSpec, index: int, reached: Reached, m: NotMeasured) -> NotMeasuredRecord:
    """The journal record of plan sample ``index`` found too dark or too bright to measure (``m``, a
    calib.NotMeasured) at ``reached``; ``committed_utc`` is left for the engine to stamp."""
    sample = spec.samples[index]
    return NotMeasuredRecord(
        plan_index=index, cell=int(spec.cells[index]), theta_h_deg=float(sample["theta_h_deg"]),
        theta_d_deg=float(sample["theta_d_deg"]), phi_d_deg=float(sample["phi_d_deg"]), reason=m.reason,
        snr=_triple(m.snr), min_snr=float(m.min_snr), longest_exposure_s=float(m.longest_exposure_s),
        upper_limit=_triple(m.upper_limit), lower_limit=_triple(m.lower_limit), joints=dict(reached.joints), exposures_s=tuple(map(float, m.exposures_s)),
        frames_taken=int(m.frames_taken), frames_skipped=int(m.frames_skipped),
        raw_paths=tuple(str(p) for p in m.raw_paths), lamp_relative=float(m.lamp_relative),
        move_s=float(reached.seconds), capture_s=float(m.clock_seconds), started_utc=float(reached.started_utc))


def _triple(values) -> tuple[float, float, float]:
    a = np.asarray(values, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))
