"""Error measures between BRDFs, in the model's mapped (log-relative) domain."""
from __future__ import annotations

import numpy as np

from goniofrost.frost.model import FrostModel


def log_relative_mse(model: FrostModel, truth, estimate) -> float:
    """Mean over valid cells and channels of (to_log(truth) - to_log(estimate))^2, over the cells
    the truth has data for (NaN truth: not measured, left out; ``measured_mean``).

    truth, estimate: (n_valid, 3) BRDF in 1/sr (rows = ``model.grid.valid_cells``).
    Uses the model's mapping L = log((w x + eps) / (r + eps)); r and mu cancel, so this is
    mean((log(w x_true + eps) - log(w x_est + eps))^2). Dimensionless.
    """
    truth = np.asarray(truth, dtype=np.float64)
    estimate = np.asarray(estimate, dtype=np.float64)
    if truth.shape != estimate.shape or truth.shape != (model.grid.n_valid, 3):
        raise ValueError(f"log_relative_mse: expected two ({model.grid.n_valid}, 3) arrays, found {truth.shape} and {estimate.shape}")
    w = np.asarray(model.weight, dtype=np.float64)[:, None]
    diff = np.log(w * truth + model.eps) - np.log(w * np.maximum(estimate, 0.0) + model.eps)
    return measured_mean(diff**2)


def measured_mean(squared: np.ndarray) -> float:
    """Mean of squared errors over the entries whose truth was measured: NaN (a cell the material
    has no data for, ``rgl:PATH``) is left out; NaN when nothing was measured."""
    squared = np.asarray(squared, dtype=np.float64)
    measured = ~np.isnan(squared)
    if measured.all():
        return float(np.mean(squared))
    return float(np.mean(squared[measured])) if measured.any() else float("nan")


def batch_log_errors(model, estimate_log: np.ndarray, truth_log: np.ndarray) -> np.ndarray:
    """Log-relative MSE per material from mapped estimates; float64 (n_mat,).

    estimate_log: (n_valid, 3 n_mat) ``reconstruct_log`` output (column 3 i + c = material i,
    channel c); truth_log: (n_mat, n_valid, 3) ``model.to_log(truth)``.
    ``reconstruct`` clamps x = from_log(b) at 0, whose map is max(b, log(eps / (r + eps))),
    so this equals ``log_relative_mse(model, truth_i, reconstruct(...))`` without the exp/log
    round trip (tests/test_bench.py checks the two agree); the benchmarks score whole folds with it.
    """
    floor = np.log(model.eps) - np.log(np.asarray(model.reference, np.float64) + model.eps)
    n_mat = truth_log.shape[0]
    out = np.empty(n_mat)
    for i in range(n_mat):
        est = np.maximum(estimate_log[:, 3 * i:3 * i + 3], floor[:, None])
        out[i] = measured_mean((est - truth_log[i]) ** 2)  # NaN truth (not measured) left out
    return out
