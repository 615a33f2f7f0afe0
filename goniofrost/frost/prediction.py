"""The predicted error of one reconstruction: what its own samples say, calibrated at training.

log(predicted log-relative MSE) = b . x over 17 features of the design and the samples (5 or 11 for
older models), b from ``calibration.py``; without a calibration, E * z2. The features and why:
docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

# The material's coordinates on the model's first COORDINATES atoms (``material_coordinates``).
COORDINATES = 6
FEATURES = ("1", "log design error", "log z2", "log energy", "log m", "level", "level^2", "log spread",
            "log z2^2", "log energy^2", "log z2 log energy") + tuple(f"coordinate {k + 1}" for k in range(COORDINATES))
# The features of calibrations fitted before level and spread existed.
BASIC_FEATURES = 5
# The features of calibrations fitted before the coordinates existed.
SAMPLE_FEATURES = 11
# The checked calibration's two more (``check_cells``): log of the sentinels' error and of the
# check cells' (``sentinel.check_error``), measured with the first batch and never fitted.
CHECK_FEATURES = ("log sentinel error", "log check error")
CHECKED_FEATURES = len(FEATURES) + len(CHECK_FEATURES)
UNCALIBRATED = {"coefficients": [0.0, 1.0, 1.0, 0.0, 0.0], "m_range": [1, 10**9],
                "typical_log_z2": 0.0, "typical_log_energy": 0.0}
# (feature, sign) of the coefficients held to a sign (``fit_coefficients``): along any design the
# design error falls and m' rises with every sample, so with these signs a typical material's
# predicted error never rises with m (``predict_typical`` varies in nothing else).
SIGNED = ((FEATURES.index("log design error"), 1.0), (FEATURES.index("log m"), -1.0))


@dataclass(frozen=True)
class Features:
    """What a reconstruction's error is predicted from, each a float or an array (broadcast
    together): ``design_error`` (of exact samples), ``z2`` and ``energy`` (``material_features``),
    ``m`` the samples; ``level`` and ``spread`` (``sample_level``; None: the first BASIC_FEATURES
    only), ``coordinates`` (..., COORDINATES) (``material_coordinates``; None: without) and
    ``checks`` (..., 2) the sentinels' and the check cells' errors (CHECK_FEATURES; None: without)."""

    design_error: object
    z2: object
    energy: object
    m: object
    level: object = None
    spread: object = None
    coordinates: object = None
    checks: object = None


def fit_coefficients(x: np.ndarray, y: np.ndarray, signed=None) -> np.ndarray:
    """Fit y (records,) on x (records, f >= BASIC_FEATURES, the columns of FEATURES in order) by
    least squares with the coefficients of ``signed`` ((feature, sign) pairs; None: SIGNED) held
    to their sign: float64 (f,).

    When plain least squares gives every sign, its coefficients are returned as they are. Otherwise
    the exact sign-constrained solution: the admissible fit of smallest residual among those with
    each nonempty subset of the signed coefficients fixed at 0 (the first on ties). Why the signs:
    docs/explanations/bayesian-design.md.
    """
    signed = SIGNED if signed is None else signed
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    if all(sign * beta[j] >= 0 for j, sign in signed):
        return beta
    best, best_rss = None, np.inf
    for count in range(1, len(signed) + 1):
        for fixed in itertools.combinations([j for j, _ in signed], count):
            keep = [j for j in range(x.shape[1]) if j not in fixed]
            trial = np.zeros(x.shape[1])
            trial[keep] = np.linalg.lstsq(x[:, keep], y, rcond=None)[0]
            rss = float(np.sum((y - x @ trial) ** 2))
            if all(sign * trial[j] >= 0 for j, sign in signed) and rss < best_rss:
                best, best_rss = trial, rss
    return best


def calibration_of(model) -> dict:
    """The model's predicted-error calibration (UNCALIBRATED when it has none)."""
    stored = (getattr(model, "noise", None) or {}).get("calibration")
    return stored if stored else UNCALIBRATED


def feature_matrix(features: Features, m_range, feature_range=None) -> np.ndarray:
    """float64 (..., 11) features of FEATURES (``features`` broadcast), or (..., 5) of the first
    five when its level and spread are None, or (..., 17) with its coordinates. m is clamped to
    ``m_range``. feature_range: [lows, highs] of (log z2, log energy, level, log spread[, the
    coordinates]) that the features are computed within (clamped: the quadratic terms must not
    extrapolate beyond the materials they were fitted on; samples that far are out of the model
    anyway), None: no clamping. With its checks (and the coordinates): (..., CHECKED_FEATURES),
    their logs clamped like the others when feature_range has them."""
    design_error, z2, energy, m = features.design_error, features.z2, features.energy, features.m
    level, spread, coordinates, checks = features.level, features.spread, features.coordinates, features.checks
    if checks is not None:
        base = feature_matrix(replace(features, checks=None), m_range, feature_range)
        logs = np.log(np.maximum(np.asarray(checks, dtype=np.float64), 1e-12))
        at = 4 + COORDINATES
        if feature_range is not None and len(feature_range[0]) > at:
            logs = np.clip(logs, feature_range[0][at:at + 2], feature_range[1][at:at + 2])
        return np.concatenate([base, np.broadcast_to(logs, base.shape[:-1] + logs.shape[-1:])], axis=-1)
    lo, hi = m_range
    parts = list(np.broadcast_arrays(np.log(design_error), np.log(z2), np.log(energy),
                                     np.log(np.clip(m, lo, hi)).astype(np.float64)))
    if level is not None:
        raw = list(np.broadcast_arrays(parts[1], parts[2], np.asarray(level, np.float64), np.log(spread)))
        if feature_range is not None:
            raw = [np.clip(v, a, b) for v, a, b in zip(raw, *feature_range)]
        log_z2, log_energy, level, log_spread = raw
        parts[1], parts[2] = log_z2, log_energy
        parts += [level, level ** 2, log_spread, log_z2 ** 2, log_energy ** 2, log_z2 * log_energy]
        parts = list(np.broadcast_arrays(*parts))
    x = np.stack([np.ones_like(parts[0])] + list(parts), axis=-1)
    if level is None or coordinates is None:
        return x
    c = np.asarray(coordinates, dtype=np.float64)
    if feature_range is not None and len(feature_range[0]) > 4:
        c = np.clip(c, feature_range[0][4:4 + COORDINATES], feature_range[1][4:4 + COORDINATES])
    return np.concatenate([x, np.broadcast_to(c, x.shape[:-1] + c.shape[-1:])], axis=-1)


def feature_range_of(z2, energy, level, spread, coordinates=None) -> list[list[float]]:
    """[lows, highs] of (log z2, log energy, level, log spread[, the coordinates (records,
    COORDINATES)]) over records (``feature_matrix``)."""
    raw = np.stack([np.log(z2), np.log(energy), np.asarray(level, np.float64), np.log(spread)])
    if coordinates is not None:
        raw = np.concatenate([raw, np.asarray(coordinates, np.float64).T])
    return [raw.min(axis=1).tolist(), raw.max(axis=1).tolist()]


def predict(calibration: dict, features: Features) -> np.ndarray:
    """Predicted log-relative MSE (float64, broadcast shape of the ``features``). Their level and
    spread are needed by a calibration of more than BASIC_FEATURES coefficients, the coordinates
    by one of more than SAMPLE_FEATURES, the checks by the checked calibration (CHECKED_FEATURES,
    ``checked_of``); a calibration of fewer ignores them."""
    beta = np.asarray(calibration["coefficients"], dtype=np.float64)
    if beta.size > BASIC_FEATURES and features.level is None:
        raise ValueError("predict: this calibration needs the samples' level and spread")
    if beta.size > SAMPLE_FEATURES and features.coordinates is None:
        raise ValueError("predict: this calibration needs the material's coordinates")
    if beta.size > len(FEATURES) and features.checks is None:
        raise ValueError("predict: this calibration needs the sentinels' and the check cells' error")
    full = beta.size > BASIC_FEATURES
    used = replace(features, level=features.level if full else None, spread=features.spread if full else None,
                   coordinates=features.coordinates if beta.size > SAMPLE_FEATURES else None,
                   checks=features.checks if beta.size > len(FEATURES) else None)
    x = feature_matrix(used, calibration["m_range"], calibration.get("feature_range"))
    return np.exp(x @ beta)


def checked_of(model) -> dict | None:
    """The model's checked calibration (``check_cells``: 19 features, the bound on nested
    residuals, the check ``cells``), None for a model without one."""
    return calibration_of(model).get("checked") or None


def predict_typical(calibration: dict, design_error, m) -> np.ndarray:
    """Predicted error of a typical material (z2, energy, spread at their training geometric
    means, level at its mean); what a design can promise before any sample is measured."""
    return predict(calibration, Features(design_error, np.exp(calibration["typical_log_z2"]),
                                         np.exp(calibration["typical_log_energy"]), m,
                                         calibration.get("typical_level", 0.0),
                                         np.exp(calibration.get("typical_log_spread", 0.0)),
                                         np.asarray(calibration.get("typical_coordinates", np.zeros(COORDINATES)))))


def material_features(post, columns, t: int) -> tuple[float, float, float]:
    """(design error, z2, energy) of one material from a posterior's columns (its channels)."""
    cols = np.asarray(columns)
    z2 = float(np.mean(post.loo_residuals[:, cols] ** 2 / post.loo_variance[:, cols]))
    energy = float(np.mean(post.coefficients[:, cols] ** 2) * t)
    return float(np.mean(post.design_error[cols])), max(z2, 1e-12), max(energy, 1e-12)


def material_coordinates(coefficients, columns, t: int) -> np.ndarray:
    """float64 (COORDINATES,): the material's posterior coefficients (K, c) on the first
    COORDINATES atoms times sqrt(t), averaged over its ``columns`` (channels); zeros for atoms a
    model of fewer than COORDINATES lacks. A typical training material's are of order 1 (the
    prior variance is 1 / t): which kind of material it is, well determined by a few samples."""
    values = np.asarray(coefficients, dtype=np.float64)[:COORDINATES, np.asarray(columns)].mean(axis=1) * np.sqrt(t)
    return np.pad(values, (0, COORDINATES - values.size))


def prequential_score(one_step, columns) -> float:
    """The mean of ``posterior.prequential_errors`` rows 1.. over the material's ``columns``:
    every sample predicted from the ones measured before it (row 0, the prior's prediction of
    the first, says how far the material is from the training mean, not how well the model
    extrapolates for it); about 1 when the model describes the material. one_step: (l, c) in
    measurement order; 1.0 when l < 2 (nothing predicted yet)."""
    values = np.asarray(one_step, dtype=np.float64)[1:, np.asarray(columns)]
    return float(values.mean()) if values.size else 1.0


def sample_level(b, columns) -> tuple[float, float]:
    """(level, spread) of one material: the mean and the variance (floored at 1e-12) of its
    centred mapped samples b (l, c) over the sampled cells and its ``columns`` (channels)."""
    values = np.asarray(b, dtype=np.float64)[:, np.asarray(columns)]
    return float(values.mean()), max(float(values.var()), 1e-12)
