"""Every pose that could measure a (w_i, w_o) pair, and why each can or cannot.

A pair has up to four candidates: two inverse-kinematics branches, each also with light and camera
swapped (reciprocity). A candidate is usable when its joints are within limits and the camera can
measure it (``planner.view``).
"""
from __future__ import annotations

import numpy as np

from .kinematics import Reason, arm_side, forward, inverse, on_lattice
from .rig import Rig
from .view import beam_covers, light_reaches, roi_pixels

MEASURABILITY = (Reason.PATCH_PIXELS, Reason.LAMP_BEAM, Reason.LIGHT_GRAZING)


def candidate_poses(rig: Rig, w_i, w_o, *, reciprocity: bool = True, steps=None):
    """Candidate poses (n, k, 3) deg (commanded), usable (n, k), reasons (n, k) uint8 of pairs
    (n, 3): k = 2 branches (+2 with light and camera swapped). ``steps`` (3,) deg: the axes'
    command lattices (``kinematics.on_lattice``): the camera's reasons are judged at the joints
    rounded onto them, the joints a plan commands (a light at 88.98 deg from the IK joints was at
    89.004 deg from the joints commanded, past the lamp's 89: capture refused the rig's own plan)."""
    parts = [inverse(rig, w_i, w_o)]
    if reciprocity:
        parts.append(inverse(rig, w_o, w_i))
    joints = np.concatenate([p.joints for p in parts], 1)
    reason = np.concatenate([p.reason for p in parts], 1)
    ok = reason == Reason.OK
    if rig.view is not None and ok.any():
        reason[ok] = measurable_reason(rig, joints[ok] if steps is None else on_lattice(joints[ok], steps))
    return joints, reason == Reason.OK, reason


def measurable_reason(rig: Rig, joints) -> np.ndarray:
    """uint8 (...): OK, PATCH_PIXELS, LAMP_BEAM or LIGHT_GRAZING for commanded joints (..., 3)
    (OK everywhere when the rig has no camera model)."""
    q = np.asarray(joints, dtype=np.float64)
    reason = np.full(q.shape[:-1], Reason.OK, dtype=np.uint8)
    if rig.view is None:
        return reason
    w_i, w_o = forward(rig, q)
    reason[roi_pixels(rig.view, w_i, w_o, arm_side(rig)) < rig.view.min_pixels] = Reason.PATCH_PIXELS
    reason[~beam_covers(rig.view, w_i)] = Reason.LAMP_BEAM
    reason[~light_reaches(rig.view, w_i)] = Reason.LIGHT_GRAZING
    return reason


def best_reason(reason: np.ndarray) -> np.ndarray:
    """uint8 (n,) of candidate reasons (n, k): OK if any candidate is usable; else the camera's
    reason if some candidate failed only on it; else the first candidate's geometric reason."""
    any_ok = np.any(reason == Reason.OK, axis=1)
    measure = np.isin(reason, MEASURABILITY)
    first_measure = reason[np.arange(len(reason)), np.argmax(measure, axis=1)]
    out = np.where(measure.any(axis=1), first_measure, reason[:, 0])
    return np.where(any_ok, np.uint8(Reason.OK), out).astype(np.uint8)
