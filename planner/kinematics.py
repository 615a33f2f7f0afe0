"""Forward and inverse kinematics: joints <-> light and view directions in the sample frame.

Joints are float arrays (..., 3) in degrees (camera_arm, sample_yaw, sample_tilt); directions are
unit vectors (..., 3) in the sample frame, z the normal. The geometry:
docs/explanations/kinematics.md.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .rig import ROLE_ORDER, Rig


class Reason(enum.IntEnum):
    """Why a (w_i, w_o) pair or a pose cannot be measured (uint8 codes, 0 = reachable)."""

    OK = 0
    ARM_SEPARATION = 1   # light and camera closer than the minimum arm separation
    ARM_LIMIT = 2        # the camera arm's angle lies outside its axis limits
    STAGE_LIMIT = 3      # the needed tilt (or yaw) lies outside the stage limits
    BELOW_SURFACE = 4    # w_i or w_o not above the sample surface (not a valid BRDF cell)
    PATCH_PIXELS = 5     # the camera sees too few patch pixels (view too grazing; planner.view)
    LAMP_BEAM = 6        # the lamp's beam does not cover the whole patch (planner.view)
    LIGHT_GRAZING = 7    # the light meets the sample beyond lamp.max_incidence_deg: too dark (planner.view)


BRANCHES = ("direct", "mirror")


@dataclass(frozen=True)
class IKResult:
    """All inverse-kinematics solutions of direction pairs of shape (...).

    ``joints``: float (..., 2, 3) degrees, branch 0 = direct, 1 = mirror, joint order
    (camera_arm, sample_yaw, sample_tilt). ``valid``: bool (..., 2). ``reason``: uint8 (..., 2)
    Reason codes (OK where valid). Joints are filled (not NaN) even when invalid, so that a
    caller can show how far outside the limits a pose lies.
    """

    joints: np.ndarray
    valid: np.ndarray
    reason: np.ndarray

    @property
    def any_valid(self) -> np.ndarray:
        """bool (...): at least one branch is reachable."""
        return self.valid.any(axis=-1)

    @property
    def best_reason(self) -> np.ndarray:
        """uint8 (...): OK if any branch is reachable, else the reason of branch 0."""
        return np.where(self.any_valid, np.uint8(Reason.OK), self.reason[..., 0]).astype(np.uint8)


def joint_offsets(rig: Rig) -> np.ndarray:
    """Zero offsets (3,) in degrees, joint order: physical angle = axis reading + offset."""
    alignment = getattr(rig, "alignment", None)
    if alignment is None:
        return np.zeros(3)
    return np.array([alignment.offsets_deg.get(name, 0.0) for name in rig.joint_names], dtype=np.float64)


def joints_array(rig: Rig, joints) -> np.ndarray:
    """Joints (..., 3) in degrees from an array or a dict keyed by axis names or roles."""
    if isinstance(joints, Mapping):
        values = []
        for axis, role in zip(rig.ordered_axes, ROLE_ORDER):
            key = axis.name if axis.name in joints else role.value
            values.append(np.asarray(joints[key], dtype=np.float64))
        return np.stack(np.broadcast_arrays(*values), axis=-1)
    return np.asarray(joints, dtype=np.float64)


def on_lattice(joints, steps) -> np.ndarray:
    """``joints`` (..., 3) deg rounded as the devices round them: round(q / step) x step (a step
    of 0: the value itself); ``steps`` (3,) deg, ``drivers.config.command_step_deg`` of each axis."""
    steps = np.asarray(steps, dtype=np.float64)
    q = np.asarray(joints, dtype=np.float64)
    safe = np.where(steps > 0, steps, 1.0)
    return np.where(steps > 0, np.round(q / safe) * safe, q)


def stage_rotation(rig: Rig, psi_deg, tau_deg) -> np.ndarray:
    """World-from-sample rotation matrices M, shape (..., 3, 3), of stage poses in degrees."""
    yaw = np.radians(np.asarray(psi_deg, dtype=np.float64) + rig.geometry.light_azimuth_deg)
    tau = np.radians(np.asarray(tau_deg, dtype=np.float64))
    cy, sy, ct, st = np.cos(yaw), np.sin(yaw), np.cos(tau), np.sin(tau)
    zero = np.zeros_like(cy)
    # Columns are the sample axes in the world: x_s = R_z(yaw) (0,1,0),
    # y_s = R_z(yaw) R_y(-tau) (0,0,1), z_s = n = R_z(yaw) R_y(-tau) (1,0,0).
    x_s = np.stack([-sy, cy, zero], -1)
    y_s = np.stack([-st * cy, -st * sy, ct], -1)
    z_s = np.stack([ct * cy, ct * sy, st], -1)
    return np.stack([x_s, y_s, z_s], -1)


def camera_direction(rig: Rig, alpha_deg) -> np.ndarray:
    """World camera direction C(alpha) = R_z(alpha) L, shape (..., 3)."""
    a = np.radians(np.asarray(alpha_deg, dtype=np.float64) + rig.geometry.light_azimuth_deg)
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1)


def forward(rig: Rig, joints) -> tuple[np.ndarray, np.ndarray]:
    """Light and view directions (w_i, w_o), unit (..., 3) in the sample frame, of joints (..., 3) deg
    as the axes read them (the rig's alignment offsets are added)."""
    q = joints_array(rig, joints) + joint_offsets(rig)
    M = stage_rotation(rig, q[..., 1], q[..., 2])
    light = np.broadcast_to(np.asarray(rig.geometry.light_direction), q.shape)
    C = camera_direction(rig, q[..., 0])
    # Sample frame = M^T world.
    w_i = np.einsum("...ji,...j->...i", M, light)
    w_o = np.einsum("...ji,...j->...i", M, C)
    return w_i, w_o


def arm_side(rig: Rig) -> float:
    """+1 if the camera arm works counter-clockwise of the light (its limits' middle >= 0), else -1."""
    lo, hi = rig.axis("camera_arm").limits_deg
    return 1.0 if lo + hi >= 0 else -1.0


def inverse(rig: Rig, w_i, w_o) -> IKResult:
    """Every joint solution reproducing (w_i, w_o) (unit or not, (..., 3), sample frame): the
    targets to command (the rig's alignment offsets are taken off the geometric solution).

    See the module Notes for the two branches. Vectorised; no Python loop over pairs.
    """
    w_i, w_o = (_unit(np.asarray(w, dtype=np.float64)) for w in (w_i, w_o))
    cross = np.cross(w_i, w_o)
    sin_a = np.linalg.norm(cross, axis=-1)
    alpha = arm_side(rig) * np.arctan2(sin_a, np.sum(w_i * w_o, axis=-1))  # radians, signed
    with np.errstate(invalid="ignore", divide="ignore"):
        n_l = w_i[..., 2]                                           # n . L = cos theta_i
        n_p = (w_o[..., 2] - n_l * np.cos(alpha)) / np.sin(alpha)   # n . L_perp
        n_z = cross[..., 2] / np.sin(alpha)                         # n . z (direct branch)
    off = joint_offsets(rig)
    psi = np.degrees(np.arctan2(n_p, n_l)) - off[1]
    tau = np.degrees(np.arctan2(n_z, np.hypot(n_l, n_p)))
    psi = _wrap_into(psi, rig.axis("sample_yaw").limits_deg)
    alpha_deg = np.degrees(alpha) - off[0]
    joints = np.stack([np.stack([alpha_deg, psi, tau - off[2]], -1), np.stack([alpha_deg, psi, -tau - off[2]], -1)], -2)
    reason = np.stack([pose_reason(rig, joints[..., b, :], w_i, w_o) for b in range(2)], -1)
    return IKResult(joints=joints, valid=reason == Reason.OK, reason=reason)


def pose_reason(rig: Rig, joints: np.ndarray, w_i=None, w_o=None) -> np.ndarray:
    """Reason code (uint8, shape (...)) why commanded joints (..., 3) deg cannot be used; OK if they
    can. The limits hold for the commanded joints; the stage's tilt limit and the arm separation
    for the physical angles (joints + alignment offsets)."""
    q = np.asarray(joints, dtype=np.float64)
    phys = q + joint_offsets(rig)
    g = rig.geometry
    arm, yaw, tilt = rig.ordered_axes
    reason = np.full(q.shape[:-1], Reason.OK, dtype=np.uint8)
    stage_bad = ~(_within(q[..., 1], yaw.limits_deg) & _within(q[..., 2], tilt.limits_deg)
                  & (np.abs(phys[..., 2]) <= g.tilt_limit_deg + _EPS_DEG))
    reason[stage_bad | ~np.isfinite(q[..., 1:]).all(-1)] = Reason.STAGE_LIMIT
    reason[~_within(q[..., 0], arm.limits_deg)] = Reason.ARM_LIMIT
    # Precedence: the arm separation is the most fundamental (light and camera physically clash).
    reason[~(np.abs(phys[..., 0]) >= g.min_arm_separation_deg - _EPS_DEG)] = Reason.ARM_SEPARATION
    if w_i is not None:
        reason[(np.asarray(w_i)[..., 2] <= 0) | (np.asarray(w_o)[..., 2] <= 0)] = Reason.BELOW_SURFACE
    return reason


# Limits are compared with this slack (degrees) so that a target exactly on a limit,
# up to floating-point rounding, is accepted.
_EPS_DEG = 1e-9


def _within(x: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    return (x >= limits[0] - _EPS_DEG) & (x <= limits[1] + _EPS_DEG)


def _wrap_into(angle_deg: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    """Shift angles by multiples of 360 deg into the limits where possible (else leave as is)."""
    out = np.asarray(angle_deg, dtype=np.float64).copy()
    for shift in (-360.0, 360.0):
        move = ~_within(out, limits) & _within(out + shift, limits)
        out[move] += shift
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)
