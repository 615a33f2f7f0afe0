"""Sentinel samples: a few cells the design leaves empty, measured as a held-out check.

``cells`` chooses them by geometry (farthest points among cells with theta_d > 80 or
theta_h > 70 degrees); ``check_error`` is their mean squared mapped error under the posterior of
the design's samples. Why: docs/explanations/sentinels.md.
"""
from __future__ import annotations

import numpy as np

from goniofrost.core.grid import MerlGrid
from goniofrost.frost.prediction import calibration_of

# Cells reserved as sentinels (measured once, with the first batch).
SENTINELS = 3
# The region the A-optimal design leaves empty (degrees).
THETA_D_MIN, THETA_H_MIN = 80.0, 70.0
# The check flags a capture whose simultaneous sentinel score exceeds this conformal quantile
# of the held-out training materials' (at most 5 % of materials like the training ones flagged).
SENTINEL_CONFIDENCE = 0.95


def region(grid: MerlGrid) -> np.ndarray:
    """bool (n_valid,): the valid cells with theta_d > THETA_D_MIN or theta_h > THETA_H_MIN (lower
    cell edges)."""
    theta_h, theta_d, _ = (np.degrees(a) for a in grid.flat_angles(grid.valid_cells))
    return (theta_d > THETA_D_MIN) | (theta_h > THETA_H_MIN)


def cells(grid: MerlGrid, count: int = SENTINELS, candidates: np.ndarray | None = None) -> np.ndarray:
    """int64 (count,) valid-cell positions: farthest-point sampling over the 6-vectors (w_i, w_o)
    of the candidate cells (bool (n_valid,), default all) in ``region``, starting at the one
    farthest from their mean; fewer when the region holds fewer, none when it is empty.
    Deterministic (ties: the lowest position). Two of the default three are one rig pose, on
    purpose: docs/explanations/sentinels.md.
    """
    mask = region(grid) if candidates is None else region(grid) & np.asarray(candidates, bool)
    where = np.flatnonzero(mask)
    if where.size == 0 or count < 1:
        return np.zeros(0, dtype=np.int64)
    w_i, w_o = grid.cell_directions(grid.valid_cells[where])
    x = np.concatenate([w_i, w_o], axis=1)
    picks = [int(np.argmax(((x - x.mean(axis=0)) ** 2).sum(axis=1)))]
    distance = ((x - x[picks[0]]) ** 2).sum(axis=1)
    while len(picks) < min(count, where.size):
        picks.append(int(np.argmax(distance)))
        distance = np.minimum(distance, ((x - x[picks[-1]]) ** 2).sum(axis=1))
    return where[picks].astype(np.int64)


def check_error(rows: np.ndarray, coefficients: np.ndarray, b: np.ndarray, columns) -> float:
    """The mean squared mapped error at the sentinels of one material: rows (s, K) dictionary
    rows of the sentinel cells, coefficients (K, c) the posterior mean of the design's samples,
    b (s, c) the sentinels' mapped values minus mu, ``columns`` the material's channels; floored
    at 1e-12 (log-relative MSE units, as the whole error)."""
    cols = np.asarray(columns)
    miss = np.asarray(b, np.float64)[:, cols] - np.asarray(rows, np.float64) @ np.asarray(coefficients)[:, cols]
    return max(float(np.mean(miss ** 2)), 1e-12)


def calibrated_cells(model) -> np.ndarray:
    """int64 (s,): the sentinel cells the model's bound was calibrated with (empty: none, a model
    trained before the check)."""
    bound = calibration_of(model).get("bound") or {}
    return np.asarray((bound.get("sentinel") or {}).get("cells", []), dtype=np.int64)


def measured_check_errors(model, cells, values, coefficients) -> np.ndarray:
    """float64 (c / 3,): ``check_error`` of every material measured at the sentinel ``cells``
    (int64 (s,) valid-cell positions): ``values`` (s, c) their BRDF in 1/sr, three channels per
    material; ``coefficients`` (K, c) the posterior mean of each material's design samples."""
    cells = np.asarray(cells, dtype=np.int64)
    b = model.to_log(np.asarray(values, np.float64), cells) - np.asarray(model.mean, np.float64)[cells][:, None]
    rows = np.asarray(model.dictionary[cells], np.float64)
    return np.array([check_error(rows, coefficients, b, [j, j + 1, j + 2]) for j in range(0, b.shape[1], 3)])
