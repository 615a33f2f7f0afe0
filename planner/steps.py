"""Joint targets on the axes' command lattices, as close to their cells as the lattices allow.

``on_steps`` searches the lattice joints that bring each measured direction closest to its cell in
the grid's index space. Why and how: docs/explanations/kinematics.md.
"""
from __future__ import annotations

import itertools

import numpy as np

from goniofrost.core.grid import HALF_PI, MerlGrid, dirs_to_half_diff

from .candidates import measurable_reason
from .kinematics import Reason, forward, on_lattice, pose_reason
from .rig import Rig

# The search: within SPAN_DEG of the IK joints on every axis (a Dynamixel count is 0.088 deg:
# both neighbours and a move of the others to match; a wider box let a coarse grid trade tenths
# of a degree of theta_i for a slightly closer node), POINTS values per axis and level, each
# level's span a ZOOM-th of the last (never below the axis's step: a lattice axis keeps its
# neighbours). Every joint ends within SPAN_DEG (+ half its step) of the IK's.
SPAN_DEG = 0.1
POINTS = 7
ZOOM = 3.0
LEVELS = 7


def cell_miss(rig: Rig, grid: MerlGrid, joints: np.ndarray, cells: np.ndarray, weights=None) -> np.ndarray:
    """float64 (...): the squared index-space distance (module doc) between the directions of
    commanded ``joints`` (..., 3) and the grid nodes ``cells`` (..., 3) (i_th, i_td, i_pd);
    ``weights`` (..., 3): each axis's squared index difference times this instead (default 1, 1
    and sin(theta_h of the cell))."""
    x_th, x_td, x_pd = grid.fractional_indices(*dirs_to_half_diff(*forward(rig, joints)))
    cells = np.asarray(cells, dtype=np.float64)
    period = grid.n_pd
    d_pd = np.minimum(_wrapped(x_pd - cells[..., 2], period), _wrapped(-x_pd - cells[..., 2], period))
    if weights is None:
        weight = np.sin((cells[..., 0] / grid.n_th) ** 2 * HALF_PI)
        return (x_th - cells[..., 0]) ** 2 + (x_td - cells[..., 1]) ** 2 + (weight * d_pd) ** 2
    w = np.asarray(weights, dtype=np.float64)
    return w[..., 0] * (x_th - cells[..., 0]) ** 2 + w[..., 1] * (x_td - cells[..., 1]) ** 2 + w[..., 2] * d_pd ** 2


def _wrapped(d: np.ndarray, period: float) -> np.ndarray:
    return np.abs(np.mod(d + period / 2.0, period) - period / 2.0)


def on_steps(rig: Rig, grid: MerlGrid, joints: np.ndarray, cells: np.ndarray, steps, weights=None) -> np.ndarray:
    """Commanded joints (n, 3) deg on the lattices of ``steps`` (3,) deg (``on_lattice``) closest
    to their cells (n, 3) in the grid's index space (module doc), among the joints the rig can
    use (limits, the arm's separation); a sample whose camera could not measure at its best joints
    (the patch at the edge of what ``planner.view`` allows) keeps its plain rounding, which
    ``planner.candidates`` judged measurable when the pose was chosen (``candidate_poses``'s
    ``steps``)."""
    q0 = np.asarray(joints, dtype=np.float64).reshape(-1, 3)
    cells = np.asarray(cells, dtype=np.float64).reshape(-1, 3)
    steps = np.asarray(steps, dtype=np.float64)
    plain = on_lattice(q0, steps)
    w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1, 3)
    best, best_miss = plain, cell_miss(rig, grid, plain, cells, w)
    centre, span = q0, np.full(3, SPAN_DEG)
    offsets = np.array(list(itertools.product(np.linspace(-1.0, 1.0, POINTS), repeat=3)))  # (P, 3)
    for _ in range(LEVELS):
        box = np.clip(centre[:, None, :] + offsets[None] * span, q0[:, None, :] - SPAN_DEG, q0[:, None, :] + SPAN_DEG)
        trial = on_lattice(box, steps)                                                  # (n, P, 3)
        miss = cell_miss(rig, grid, trial, np.broadcast_to(cells[:, None, :], trial.shape),
                         None if w is None else np.broadcast_to(w[:, None, :], trial.shape))
        miss[pose_reason(rig, trial) != Reason.OK] = np.inf  # e.g. past the arm's limit: not a pose
        pick = np.argmin(miss, axis=1)
        level_best = trial[np.arange(len(q0)), pick]
        better = miss[np.arange(len(q0)), pick] < best_miss
        best = np.where(better[:, None], level_best, best)
        best_miss = np.where(better, miss[np.arange(len(q0)), pick], best_miss)
        centre = best
        span = np.maximum(span / ZOOM, steps)
    # the camera's check costs ~30 us a pose: on the result only (the moved joints rarely change it)
    usable = measurable_reason(rig, best) == Reason.OK
    return np.where(usable[:, None], best, plain)
