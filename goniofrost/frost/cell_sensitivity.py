"""How much a model expects a cell's mapped value to change when the direction measured is off.

Per grid axis (theta_h, theta_d, phi_d), the mean over a cell's neighbours one index away of
(mu_c - mu_n)^2 + sum_k (D_ck - D_nk)^2 prior_var_k: the weights of ``planner.steps``
(docs/explanations/kinematics.md).
"""
from __future__ import annotations

import numpy as np

from goniofrost.frost.posterior import prior_variance


def axis_weights(model, cells) -> np.ndarray:
    """float64 (n, 3): the expected squared change of the mapped value per index step along
    theta_h, theta_d and phi_d (module doc) at ``cells`` (n, 3) (i_th, i_td, i_pd) of the
    model's grid; 0 for an axis with no valid neighbour."""
    grid = model.grid
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    prior = prior_variance(model)
    mean = np.asarray(model.mean, dtype=np.float64)
    sizes = np.array([grid.n_th, grid.n_td, grid.n_pd])
    # the cell and its six neighbours (axis, -1 / +1), rows of one valid_position call (each call
    # builds a lookup of the whole grid)
    shifted = np.repeat(cells[None], 7, axis=0)                                        # (7, n, 3)
    for j, (axis, step) in enumerate((a, s) for a in range(3) for s in (-1, 1)):
        shifted[1 + j, :, axis] += step
    shifted[..., 2] %= grid.n_pd                                                       # phi_d wraps round
    inside = np.all((shifted >= 0) & (shifted < sizes), axis=-1)
    positions = np.where(inside, grid.valid_position(grid.flat_index(*np.clip(shifted, 0, sizes - 1).T).T), -1)
    here = positions[0]
    if np.any(here < 0):
        raise ValueError(f"axis_weights: cell {cells[np.argmax(here < 0)].tolist()} is not a valid cell of the "
                         f"model's {grid.shape} grid")
    d_here = np.asarray(model.dictionary[here], dtype=np.float64)                     # (n, K)
    weights = np.zeros(cells.shape)
    for axis in range(3):
        total, count = np.zeros(len(cells)), np.zeros(len(cells))
        for there in positions[1 + 2 * axis:3 + 2 * axis]:
            ok = there >= 0
            d_there = np.asarray(model.dictionary[there[ok]], dtype=np.float64)
            total[ok] += (mean[here[ok]] - mean[there[ok]]) ** 2 + ((d_here[ok] - d_there) ** 2) @ prior
            count[ok] += 1
        weights[:, axis] = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return weights
