"""Turn a FROST plan into a rig plan: a pose per sample, in the capture order of least motion time.

``schedule_plan(plan_doc, rig)`` returns the plan with samples in capture order, each with
``selection_index``, ``joints`` {axis: degrees}, ``move_s``, ``branch`` and
``light_camera_swapped``; the top level gains ``rig``, ``alignment``, ``planned_motion_s``,
``return_home_s`` and ``selection_order_motion_s``. ``schedule_batches`` orders each batch of a
nested design on its own and adds ``batch_ends``.
"""
from __future__ import annotations

import copy
from typing import Mapping

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid, half_diff_to_dirs

from .candidates import best_reason, candidate_poses, measurable_reason
from .kinematics import BRANCHES, Reason, forward
from .motion import path_time
from .order import Tour, fixed_order_tour, plan_tour
from .rig import Rig
from .steps import on_steps

# Joint targets must reproduce their cell's theta_i, theta_o and angle(w_i, w_o) this closely (deg).
REPRODUCE_TOL_DEG = 0.01


class UnreachableSampleError(GoniofrostError, ValueError):
    """A plan sample that no pose of the rig can measure (names the sample and the reason)."""


def schedule_plan(plan_doc: Mapping, rig: Rig, *, reciprocity: bool = True, restarts: int = 8,
                  steps=None, axis_weights=None) -> dict:
    """A copy of ``plan_doc`` with joints, capture order and motion times for ``rig`` (see module
    doc). ``steps``: (3,) deg between the positions each axis (in ``rig.joint_names`` order) can be
    commanded to (``drivers.config.command_step_deg``; 0: any): the joints are then put on those
    lattices as close to their cells as they allow (``planner.steps``), each grid axis's miss
    weighted by ``axis_weights`` (n, 3) of the samples in the document's order (e.g.
    ``goniofrost.frost.cell_sensitivity.axis_weights``; None: ``planner.steps``'s default); steps
    None: the IK joints."""
    return _schedule(plan_doc, rig, [len(plan_doc["samples"])], reciprocity, restarts, steps, axis_weights)


def schedule_batches(plan_doc: Mapping, rig: Rig, batch_ends, *, reciprocity: bool = True,
                     restarts: int = 8, steps=None, axis_weights=None) -> dict:
    """``schedule_plan`` batch by batch (see module doc); ``batch_ends`` increasing, the last = n."""
    ends = [int(e) for e in batch_ends]
    n = len(plan_doc["samples"])
    if not ends or ends[-1] != n or any(b <= a for a, b in zip([0] + ends[:-1], ends)):
        raise ValueError(f"batch_ends: expected increasing sample counts ending at {n}, found {ends}")
    return _schedule(plan_doc, rig, ends, reciprocity, restarts, steps, axis_weights) | {"batch_ends": ends}


def _schedule(plan_doc: Mapping, rig: Rig, ends: list[int], reciprocity: bool, restarts: int, steps=None,
              axis_weights=None) -> dict:
    """Order each batch [e_{k-1}, e_k) of selection indices for least motion, each starting where
    the previous one ended (one batch: the whole plan from home)."""
    samples = list(plan_doc["samples"])
    w_i, w_o = sample_directions(plan_doc)
    # (n, k): usable, and measurable at the joints commanded (on the lattices of steps)
    poses, valid, reasons = candidate_poses(rig, w_i, w_o, reciprocity=reciprocity, steps=steps)
    _refuse_unreachable(samples, valid, reasons)
    order, choice, start = [], [], rig.home
    for a, b in zip([0] + ends[:-1], ends):
        if b > a:
            part = plan_tour(rig, poses[a:b], valid[a:b], start, restarts=restarts)
            order += list(a + part.order)
            choice += list(part.choice)
            start = poses[a + part.order[-1], part.choice[-1]]
    tour = Tour(np.asarray(order, dtype=np.int64), np.asarray(choice, dtype=np.int64), 0.0)
    baseline = fixed_order_tour(rig, poses, valid, rig.home, np.arange(len(samples)))
    chosen = poses[tour.order, tour.choice]
    check_reproduction(rig, chosen, w_i[tour.order], w_o[tour.order], tour.choice >= 2)
    if steps is not None and all("cell" in s for s in samples):
        grid = MerlGrid(**plan_doc["grid"]) if "grid" in plan_doc else MerlGrid()
        cells = np.array([cell_indices(samples[i]) for i in tour.order], dtype=np.float64)
        weights = None if axis_weights is None else np.asarray(axis_weights, dtype=np.float64)[tour.order]
        chosen = on_steps(rig, grid, chosen, cells, steps, weights)
    _refuse_unmeasurable(rig, samples, tour.order, clip_to_limits(rig, chosen))
    out = {key: copy.deepcopy(value) for key, value in plan_doc.items() if key != "samples"}
    out["samples"] = _capture_samples(rig, samples, tour, chosen)
    moves = _move_times(rig, chosen)
    out["rig"] = {"name": rig.name, "file": rig.source, "kinematic_hash": rig.kinematic_hash}
    if steps is not None:
        out["rig"]["command_steps_deg"] = [float(v) for v in steps]
    out["alignment"] = None if rig.alignment is None else rig.alignment.record()
    out["planned_motion_s"] = float(moves.sum())
    out["return_home_s"] = float(moves[-1])
    out["selection_order_motion_s"] = baseline.total_s
    return out


def sample_directions(plan_doc: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """Unit (w_i, w_o), each (n, 3), of the plan's samples (from w_i/w_o, angles or cells)."""
    samples = plan_doc["samples"]
    if not samples:
        return np.zeros((0, 3)), np.zeros((0, 3))
    if all("w_i" in s and "w_o" in s for s in samples):
        return (np.array([s["w_i"] for s in samples], dtype=np.float64),
                np.array([s["w_o"] for s in samples], dtype=np.float64))
    if all("theta_h_deg" in s for s in samples):
        angles = np.radians([[s["theta_h_deg"], s["theta_d_deg"], s["phi_d_deg"]] for s in samples])
        return half_diff_to_dirs(*angles.T)
    grid = MerlGrid(**plan_doc["grid"]) if "grid" in plan_doc else MerlGrid()
    idx = np.array([cell_indices(s) for s in samples])
    return half_diff_to_dirs(*grid.cell_angles(*idx.T))


def cell_indices(sample: Mapping) -> tuple[int, int, int]:
    """(i_th, i_td, i_pd) of a plan sample (``cell`` as a list or mapping, or top-level keys)."""
    cell = sample.get("cell", sample)
    if isinstance(cell, Mapping):
        return int(cell["i_th"]), int(cell["i_td"]), int(cell["i_pd"])
    return tuple(int(c) for c in cell)


def check_reproduction(rig: Rig, joints, w_i, w_o, swapped) -> None:
    """Raise if forward(joints) misses theta_i, theta_o or angle(w_i, w_o) by > REPRODUCE_TOL_DEG."""
    f_i, f_o = forward(rig, joints)
    want_i = np.where(np.asarray(swapped)[:, None], w_o, w_i)
    want_o = np.where(np.asarray(swapped)[:, None], w_i, w_o)
    err = np.max(np.abs(pair_angles(f_i, f_o) - pair_angles(want_i, want_o)), axis=-1)
    if np.any(err > REPRODUCE_TOL_DEG):
        bad = int(np.argmax(err))
        raise AssertionError(f"joint target {bad} misses its cell by {err[bad]:.4g} deg")


def pair_angles(w_i, w_o) -> np.ndarray:
    """(theta_i, theta_o, angle between) in degrees, (..., 3), of direction pairs (..., 3)."""
    w_i, w_o = np.asarray(w_i, dtype=np.float64), np.asarray(w_o, dtype=np.float64)

    def polar(w):
        return np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2])

    between = np.arctan2(np.linalg.norm(np.cross(w_i, w_o), axis=-1), np.sum(w_i * w_o, axis=-1))
    return np.degrees(np.stack([polar(w_i), polar(w_o), between], -1))


def _refuse_unreachable(samples, valid: np.ndarray, reasons: np.ndarray) -> None:
    best = best_reason(reasons)
    for s in np.flatnonzero(~valid.any(axis=1)):
        why = Reason(int(best[s])).name
        raise UnreachableSampleError(
            f"plan sample {s} (cell {_cell_label(samples[s])}) cannot be reached on this rig: {why}")


def _refuse_unmeasurable(rig: Rig, samples, order, commanded: np.ndarray) -> None:
    """The plan's own promise, checked as the capture checks it (``capture.inputs``): every
    sample measurable at the joints written (candidates judged on the command lattices make this
    hold; a plan must never be one its capture refuses)."""
    reason = measurable_reason(rig, commanded)
    for pos in np.flatnonzero(reason != Reason.OK):
        s = int(order[pos])
        raise UnreachableSampleError(f"plan sample {s} (cell {_cell_label(samples[s])}) cannot be measured at the "
                                     f"joints it would command: {Reason(int(reason[pos])).name}")


def clip_to_limits(rig: Rig, joints: np.ndarray) -> np.ndarray:
    """Joints (..., n_axes) in degrees with values that the reachability test accepted within its
    rounding slack of a limit put exactly on it: the drivers and capture compare limits exactly."""
    lows, highs = np.array([rig.axis(name).limits_deg for name in rig.joint_names]).T
    return np.clip(joints, lows, highs)


def _capture_samples(rig: Rig, samples, tour: Tour, chosen: np.ndarray) -> list[dict]:
    chosen = clip_to_limits(rig, chosen)
    moves = _move_times(rig, chosen)
    out = []
    for pos, (s, c) in enumerate(zip(tour.order, tour.choice)):
        sample = copy.deepcopy(dict(samples[s]))
        sample["selection_index"] = int(sample.get("selection_index", s))
        sample["joints"] = {name: float(v) for name, v in zip(rig.joint_names, chosen[pos])}
        sample["branch"] = BRANCHES[int(c) % 2]
        sample["light_camera_swapped"] = bool(c >= 2)
        sample["move_s"] = float(moves[pos])
        out.append(sample)
    return out


def _move_times(rig: Rig, chosen: np.ndarray) -> np.ndarray:
    """Per-move seconds home -> chosen[0] -> ... -> chosen[-1] -> home; shape (n + 1,)."""
    return path_time(rig, chosen, start=rig.home, end=rig.home)


def _cell_label(sample: Mapping) -> str:
    try:
        return "(%d, %d, %d)" % cell_indices(sample)
    except (KeyError, TypeError, ValueError):
        return "?"


def format_table(plan_doc: Mapping) -> str:
    """A readable table of a scheduled plan: one line per sample in capture order, then totals."""
    samples = plan_doc["samples"]
    names = list(samples[0]["joints"]) if samples else []
    head = f"{'#':>3} {'sel':>4} {'cell':>15} " + " ".join(f"{n:>12}" for n in names) + \
        f" {'branch':>7} {'swap':>5} {'move_s':>7}"
    lines = [head, "-" * len(head)]
    for i, s in enumerate(samples):
        joints = " ".join(f"{s['joints'][n]:12.3f}" for n in names)
        lines.append(f"{i:>3} {s['selection_index']:>4} {_cell_label(s):>15} {joints} "
                     f"{s['branch']:>7} {'yes' if s['light_camera_swapped'] else 'no':>5} {s['move_s']:7.2f}")
    planned, baseline = plan_doc["planned_motion_s"], plan_doc["selection_order_motion_s"]
    saving = 100.0 * (1.0 - planned / baseline) if baseline > 0 else 0.0
    lines.append(f"return home: {plan_doc['return_home_s']:.2f} s; planned motion {planned:.1f} s; "
                 f"selection order {baseline:.1f} s ({saving:.0f} % saved); rig {plan_doc['rig']['name']}")
    return "\n".join(lines)
