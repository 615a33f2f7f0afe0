"""Rig time of a nested design on the simulated rig's clock, batch by batch, for test materials.

Each batch ordered as ``plan --rig`` orders it, its moves timed as the simulated axes move and each
sample's bracket by ``calib.exposure_time`` on the material's true value; no frames are rendered.
Calibration and the moves to the white reference and home are left out.
"""
from __future__ import annotations

import numpy as np

from calib.exposure_time import bracket_seconds, expected_frames, first_rungs
from goniofrost.frost import stopping
from goniofrost.frost.rig_cost import rig_camera, rig_sensor
from planner.candidates import candidate_poses
from planner.kinematics import arm_side
from planner.motion import path_time
from planner.order import plan_tour
from planner.view import roi_pixels


def capture_poses(rig, grid, cells, ends) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order (m,) positions into ``cells`` in capture order, poses (m, 3) deg, swapped (m,) bool)
    of a design's valid-cell flat indices ``cells`` (m,) measured in batches ``ends``."""
    w_i, w_o = grid.cell_directions(np.asarray(cells))
    poses, usable, _ = candidate_poses(rig, w_i, w_o)
    order, chosen, swapped, start = [], [], [], np.asarray(rig.home, np.float64)
    for a, b in zip([0] + list(ends[:-1]), ends):
        tour = plan_tour(rig, poses[a:b], usable[a:b], start)
        picked = poses[a + tour.order, tour.choice]
        order += list(a + tour.order)
        chosen.append(picked)
        swapped += list(tour.choice >= 2)
        start = picked[-1]
    return np.asarray(order, np.int64), np.concatenate(chosen), np.asarray(swapped)


def design_times(rig, grid, cells, truth: np.ndarray) -> dict:
    """Cumulative rig seconds after every batch end of the design ``cells`` (valid-cell flat
    indices (m,)) for materials ``truth`` (n_mat, m, 3) BRDF at those cells (1/sr).

    Returns "ends" (batches,), "motion" (batches,) and "exposure" (n_mat, batches) seconds.
    """
    ends = stopping.batch_ends(len(cells))
    order, poses, swapped = capture_poses(rig, grid, cells, ends)
    motion = np.cumsum(path_time(rig, poses, start=rig.home))
    w_i, w_o = grid.cell_directions(np.asarray(cells)[order])
    light = np.where(swapped[:, None], w_o, w_i)
    view = np.where(swapped[:, None], w_i, w_o)
    pixels = np.maximum(roi_pixels(rig.view, light, view, arm_side(rig)), 1.0) if rig.view is not None else \
        np.full(len(order), 100.0)
    exposure = np.array([np.cumsum(_brackets(rig, truth[k][order], light, pixels)) for k in range(truth.shape[0])])
    at = np.asarray(ends) - 1
    return {"ends": np.asarray(ends), "motion": motion[at], "exposure": exposure[:, at]}


def _brackets(rig, values: np.ndarray, light: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Seconds of each sample's bracket (m,) in capture order: values (m, 3) 1/sr, light (m, 3)."""
    camera, sensor = rig_camera(rig), rig_sensor(rig)
    ladder = camera["exposures_s"]
    previous = np.vstack([np.full((1, 3), 1 / np.pi), values[:-1]])  # the first: a white-like guess
    first = first_rungs(ladder, sensor.rates(previous, light[:, 2]), camera["saturation"])
    taken = expected_frames(ladder, sensor.rates(values, light[:, 2]), pixels, sensor, camera["saturation"],
                            camera["target_snr"], first)
    return bracket_seconds(ladder, taken)
