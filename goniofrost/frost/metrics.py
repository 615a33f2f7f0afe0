"""Error measures between BRDFs, in the model's mapped (log-relative) domain."""
from __future__ import annotations

import numpy as np

from goniofrost.frost.model import FrostModel


def log_relative_mse(model: FrostModel, truth, estimate) -> float:
    """Mean over valid cells and channels of (to_log(truth) - to_log(estimate))^2.

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
    return float(np.mean(diff**2))
