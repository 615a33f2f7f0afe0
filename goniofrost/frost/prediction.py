"""The predicted error of one reconstruction: what its own samples say, calibrated at training.

The posterior (``posterior.py``) gives the design error E (the mean predictive variance over
all cells, the same for every material measured at the same cells). What makes one material
harder than another shows in its own samples:

* z2: the mean squared closed-form leave-one-out residual at the sampled cells, each divided
  by its variance under the model (about 1 for a material the model describes well);
* energy: the mean squared posterior coefficient times t (about 1 for a typical training
  material; large for materials far from the training set).

The predicted log-relative MSE of the whole reconstructed BRDF is

    log(predicted) = b0 + b1 log(E) + b2 log(z2) + b3 log(energy) + b4 log(m'),

m' = the number of sampled cells clamped into the range the coefficients were fitted on. The
coefficients come from the model (fitted by least squares on held-out training materials,
``calibration.py``); a model without them uses b = (0, 1, 1, 0, 0), i.e. E * z2. The training
materials' samples are exact, so measured samples with their own variance get the calibrated
prediction with E computed without that variance, plus the increase of E it causes (what the
model says the measurement noise costs; ``reconstruction._posterior``).
"""
from __future__ import annotations

import numpy as np

FEATURES = ("1", "log design error", "log z2", "log energy", "log m")
UNCALIBRATED = {"coefficients": [0.0, 1.0, 1.0, 0.0, 0.0], "m_range": [1, 10**9],
                "typical_log_z2": 0.0, "typical_log_energy": 0.0}


def calibration_of(model) -> dict:
    """The model's predicted-error calibration (UNCALIBRATED when it has none)."""
    stored = (getattr(model, "noise", None) or {}).get("calibration")
    return stored if stored else UNCALIBRATED


def feature_matrix(design_error, z2, energy, m, m_range) -> np.ndarray:
    """float64 (..., 5) features of FEATURES (arguments broadcast)."""
    lo, hi = m_range
    parts = np.broadcast_arrays(np.log(design_error), np.log(z2), np.log(energy),
                                np.log(np.clip(m, lo, hi)).astype(np.float64))
    return np.stack([np.ones_like(parts[0])] + list(parts), axis=-1)


def predict(calibration: dict, design_error, z2, energy, m) -> np.ndarray:
    """Predicted log-relative MSE (float64, broadcast shape of the arguments)."""
    x = feature_matrix(design_error, z2, energy, m, calibration["m_range"])
    return np.exp(x @ np.asarray(calibration["coefficients"], dtype=np.float64))


def predict_typical(calibration: dict, design_error, m) -> np.ndarray:
    """Predicted error of a typical material (z2 and energy at their training geometric means);
    what a design can promise before any sample is measured."""
    return predict(calibration, design_error, np.exp(calibration["typical_log_z2"]),
                   np.exp(calibration["typical_log_energy"]), m)


def material_features(post, columns, t: int) -> tuple[float, float, float]:
    """(design error, z2, energy) of one material from a posterior's columns (its channels)."""
    cols = np.asarray(columns)
    z2 = float(np.mean(post.loo_residuals[:, cols] ** 2 / post.loo_variance[:, cols]))
    energy = float(np.mean(post.coefficients[:, cols] ** 2) * t)
    return float(np.mean(post.design_error[cols])), max(z2, 1e-12), max(energy, 1e-12)
