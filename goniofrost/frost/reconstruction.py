"""Reconstruction: a few BRDF samples -> the full BRDF, on the FROST dictionary.

``reconstruct_bayes`` (the default) is the posterior mean (``posterior.py``) with a predictive std
per cell and a predicted error. ``reconstruct`` is the paper's ridge regression on the first a
atoms, a = ``n_atoms`` or min(distinct sampled cells, K): s = (D_a^T D_a + eta I)^-1 D_a^T b
(eta = 40), x = (exp(D_a s + mu)(r + eps) - eps) / w, clamped >= 0. BRDF values in 1/sr.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from goniofrost.core.errors import GoniofrostError
from goniofrost.frost.model import FrostModel

ETA = 40.0


class ReconstructionError(GoniofrostError, ValueError):
    """Samples or options that cannot be used for reconstruction."""


def reconstruct(model: FrostModel, positions, values, eta: float = ETA,
                n_atoms: int | None = None) -> np.ndarray:
    """Reconstruct a BRDF from samples; returns float64 (n_valid, 3) in 1/sr.

    positions: int (l,) indices into ``grid.valid_cells`` (repeats allowed: averaged).
    values: (l, 3) BRDF samples in 1/sr (finite, >= 0).
    eta: ridge weight; n_atoms: atoms used (default min(distinct cells, K)).
    """
    positions, values = _check_samples(model, positions, values)
    unique, mean_values = average_duplicates(positions, values)
    mapped = model.to_log(mean_values, unique)
    estimate = model.from_log(reconstruct_log(model, unique, mapped, eta, n_atoms))
    _check_overflow(estimate, unique.size, f"eta={eta:g}", f": use eta > 0 (default {ETA:g}) or samples better spread over the BRDF")
    return estimate


def _check_overflow(estimate, n_cells: int, what: str, advice: str = "") -> None:
    overflow = int(np.count_nonzero(~np.isfinite(estimate)))
    if overflow:
        raise ReconstructionError(
            f"reconstruction diverged: {overflow} of {estimate.size} estimated values overflow "
            f"(beyond 1e308 1/sr); the {n_cells} sampled cells do not constrain the fit with "
            f"{what}{advice}")


@dataclass
class BayesReconstruction:
    """A posterior-mean reconstruction with its uncertainty.

    brdf: float64 (n_valid, 3) in 1/sr (clamped >= 0). mapped: float64 (n_valid, 3), the
    estimate of L = log((w x + eps) / (r + eps)) (mu added). std: float64 (n_valid, 3), the
    predictive standard deviation of that mapped value (equivalently of ln(w x + eps)),
    scaled so that its mean square over cells is ``predicted_error``. predicted_error: the
    predicted log-relative MSE of this reconstruction. design_error, z2, energy: its features
    (``prediction.py``). samples: distinct sampled cells.
    """

    brdf: np.ndarray
    mapped: np.ndarray
    std: np.ndarray | None
    predicted_error: float
    design_error: float
    z2: float
    energy: float
    samples: int
    level: float = 0.0
    spread: float = 1.0


def reconstruct_bayes(model: FrostModel, positions, values, sigmas=None,
                      with_std: bool = True) -> BayesReconstruction:
    """Posterior-mean reconstruction over all K atoms with the model's noise model.

    positions: int (l,) indices into ``grid.valid_cells`` (repeats allowed: averaged).
    values: (l, 3) BRDF samples in 1/sr (finite, >= 0). sigmas: optional (l, 3) standard
    deviations of the samples in 1/sr (added to the noise through the log map).
    with_std: also compute the per-cell predictive standard deviation (one more product).
    """
    from goniofrost.frost import posterior

    unique, _, cell_noise, post, (predicted, design, z2, energy, _, level, spread, *_) = _posterior(
        model, positions, values, sigmas)
    mu = np.asarray(model.mean, dtype=np.float64)
    if with_std:
        mapped, variance, used = posterior.mean_and_variance(model.dictionary, mu, post)
        per_channel = variance[:, np.searchsorted(used, post.group)]
        std = np.sqrt((per_channel + cell_noise[:, None]) * (predicted / design))
    else:
        mapped, std = reconstruct_mapped(model, post), None
    brdf = model.from_log(mapped)
    _check_overflow(brdf, unique.size, "the Bayesian estimate")
    return BayesReconstruction(brdf, mapped, std, predicted, design, z2, energy, int(unique.size), level, spread)


def predicted_error(model: FrostModel, positions, values, sigmas=None, scene=None) -> float:
    """The predicted log-relative MSE of ``reconstruct_bayes`` from these samples, without the
    reconstruction itself (no pass over the cells: a few milliseconds). ``scene``: a
    ``scene_error.SceneError``: the error of the scene's use (usage-weighted) instead of the
    whole BRDF's."""
    return _posterior(model, positions, values, sigmas, scene)[4][0]


def error_bound(model: FrostModel, positions, values, sigmas=None, confidence: float = 0.95, scene=None,
                sentinel=None):
    """The calibrated bound on ``reconstruct_bayes``'s error from these samples at ``confidence``
    and whether they are unlike every training material (a ``confidence.ErrorBound``; no pass over
    the cells). Its median estimate counts the samples' variance as ``predicted_error`` does.
    ``scene``: bound the error of the scene's use instead, with its own calibration.
    ``sentinel``: bool (l,), the samples that are sentinels (``frost.sentinel``): the bound is of
    the other samples, and the sentinels' error against their posterior is checked (out of the
    model, "sentinel", beyond its calibrated range). Those of them at the model's check cells
    (``check_cells``: the plan marks them too) are the check samples: when they cover every
    check cell beside the sentinels, the median and the bound are the checked calibration's. A
    design unlike every design the calibration was fitted on is out of the model too ("design":
    ``confidence.design_outside``, on the design error of exact samples)."""
    from goniofrost.frost import check_cells, prediction
    from goniofrost.frost.confidence import Evidence, error_bound as bound_of
    from goniofrost.frost.sentinel import measured_check_errors

    checked = sentinel is not None and bool(np.any(sentinel))
    if checked:
        flags, positions, values = np.asarray(sentinel, bool), np.asarray(positions), np.asarray(values, np.float64)
        geometric, checks = check_cells.measured(model, positions, flags) if scene is None else (flags, flags & False)
        complete = check_cells.complete(model, positions, checks) and bool(np.any(geometric))
        sentinels = (positions[geometric], values[geometric])
        checking = (positions[checks], values[checks])
        positions, values = positions[~flags], values[~flags]
        sigmas = None if sigmas is None else np.asarray(sigmas)[~flags]
    unique, _, _, post, (predicted, _, z2, energy, extra, level, spread, clean, coordinates) = _posterior(
        model, positions, values, sigmas, scene)
    check = float(measured_check_errors(model, *sentinels, post.coefficients)[0]) if checked and sentinels[0].size \
        else None
    checked_predicted = None
    if checked and complete:
        errors = [check, float(measured_check_errors(model, *checking, post.coefficients)[0])]
        checked_predicted = float(prediction.predict(prediction.checked_of(model), prediction.Features(
            clean, z2, energy, unique.size, level, spread, coordinates, errors)))
    return bound_of(_calibration(model, scene), predicted - extra, z2, energy, unique.size, confidence,
                    Evidence(extra, check, checked_predicted, clean))


def design_error(model: FrostModel, positions) -> float:
    """The design error of exact samples at the distinct valid-cell ``positions`` (what the
    calibration's prediction takes, ``prediction.py``): the same for every material, so a plan
    knows it before any sample is measured."""
    from goniofrost.frost import posterior

    unique = np.unique(np.asarray(positions, dtype=np.int64))
    cell_noise = posterior.cell_noise(model)
    s2 = np.asarray(model.singular_values, dtype=np.float64) ** 2
    post = posterior.fit(model.dictionary[unique], cell_noise[unique], posterior.prior_variance(model),
                         np.zeros((unique.size, 1)), s2, float(cell_noise.sum()), model.grid.n_valid)
    return float(post.design_error[0])


def _calibration(model: FrostModel, scene) -> dict:
    """The calibration of the error asked for: the model's, or the scene's (none: ``{}``, so no
    bound, and the point prediction uncalibrated)."""
    from goniofrost.frost import prediction

    if scene is None:
        return prediction.calibration_of(model)
    return scene.calibration or {}


def _posterior(model: FrostModel, positions, values, sigmas, scene=None):
    """Checked samples -> (distinct positions, their noise (u, 3), every cell's noise (n,), the
    Posterior, (predicted error, design error, z2, energy, the part of the predicted error the
    samples' own variance adds, level, spread, the design error without that variance, the
    material's coordinates)).

    The calibration was fitted on noise-free samples, so the samples' own variance enters the
    prediction as what the model says it costs: the design error with it minus the design error
    without it (the extra posterior variance, averaged over every cell), added to the calibrated
    prediction made with the design error without it. With a ``scene`` the design error is the
    usage-weighted one (trace(M Sigma) + sum u sigma^2) and the calibration the scene's.
    """
    from goniofrost.frost import posterior, prediction

    positions, values = _check_samples(model, positions, values)
    unique, mean_values, noise_extra = _average_with_sigmas(model, positions, values, sigmas)
    cell_noise = posterior.cell_noise(model)
    noise = cell_noise[unique][:, None] + noise_extra
    mu = np.asarray(model.mean, dtype=np.float64)
    b = model.to_log(mean_values, unique) - mu[unique][:, None]
    s2 = np.asarray(model.singular_values, dtype=np.float64) ** 2
    rows, prior = model.dictionary[unique], posterior.prior_variance(model)
    total, n = float(cell_noise.sum()), model.grid.n_valid
    if scene is not None:
        s2, total, n = scene.matrix, scene.noise_total, 1
    post = posterior.fit(rows, noise, prior, b, s2, total, n)
    design, z2, energy = prediction.material_features(post, [0, 1, 2], model.n_signals)
    level, spread = prediction.sample_level(b, [0, 1, 2])
    clean = design
    if np.any(noise_extra > 0):
        clean = float(np.mean(posterior.fit(rows, cell_noise[unique], prior, b[:, :1], s2, total, n).design_error))
    fitted = _calibration(model, scene) or prediction.UNCALIBRATED
    coordinates = prediction.material_coordinates(post.coefficients, [0, 1, 2], model.n_signals)
    predicted = float(prediction.predict(fitted, prediction.Features(clean, z2, energy, unique.size, level, spread,
                                                                     coordinates)))
    extra = max(design - clean, 0.0)
    return unique, noise, cell_noise, post, (predicted + extra, design, z2, energy, extra, level, spread, clean,
                                             coordinates)


def reconstruct_mapped(model: FrostModel, post) -> np.ndarray:
    """D s_hat + mu over every valid cell: float64 (n_valid, c)."""
    with threadpool_limits(limits=1, user_api="blas"):
        estimate = model.dictionary @ post.coefficients.astype(np.float32)
    return estimate.astype(np.float64) + np.asarray(model.mean, dtype=np.float64)[:, None]


def _average_with_sigmas(model, positions, values, sigmas):
    """Distinct positions, mean values and the samples' own mapped variance (u, 3) (0 without sigmas).

    The mean of k samples has the variance sum(sigma^2) / k^2 (independent errors).
    """
    unique, mean_values = average_duplicates(positions, values)
    if sigmas is None:
        return unique, mean_values, np.zeros_like(mean_values)
    sigmas = np.asarray(sigmas, dtype=np.float64)
    if sigmas.shape != values.shape:
        raise ReconstructionError(f"sigmas: expected shape {values.shape} like the values, found {sigmas.shape}")
    check_values(sigmas, lambda i: f"sample {i} standard deviation",
                 expected="a finite standard deviation >= 0 (1/sr)")
    _, var_sum = average_duplicates(positions, sigmas ** 2)
    counts = np.bincount(np.searchsorted(unique, positions), minlength=unique.size)[:, None]
    sigma_mean = np.sqrt(var_sum / counts)
    w = np.asarray(model.weight, dtype=np.float64)[unique]
    from goniofrost.frost.posterior import log_map_variance
    return unique, mean_values, log_map_variance(mean_values, sigma_mean, w, model.eps)


def reconstruct_log(model: FrostModel, positions, log_values, eta: float = ETA,
                    n_atoms: int | None = None) -> np.ndarray:
    """Ridge reconstruction in the mapped domain.

    positions: int (l,) distinct indices into valid cells.
    log_values: (l, 3) or (l,) mapped samples ``model.to_log(values, positions)`` (mu NOT
        subtracted). Returns float64 (n_valid, 3) (or (n_valid,)): D_a s + mu.
    """
    positions = np.asarray(positions, dtype=np.int64)
    b = np.asarray(log_values, dtype=np.float64)
    a = _atom_count(model, np.unique(positions).size, n_atoms)
    if not (np.isfinite(eta) and eta >= 0):
        raise ReconstructionError(f"eta (--eta): expected a finite number >= 0, found {eta!r}")
    mu = np.asarray(model.mean, dtype=np.float64)
    d_l = np.asarray(model.dictionary[positions, :a], dtype=np.float64)
    rhs = b - (mu[positions][:, None] if b.ndim == 2 else mu[positions])
    s = np.linalg.solve(d_l.T @ d_l + eta * np.eye(a), d_l.T @ rhs)
    # (n x a) @ (a x 3) is too thin for OpenBLAS threads to pay off (they spin on a busy host).
    with threadpool_limits(limits=1, user_api="blas"):
        estimate = model.dictionary[:, :a] @ s.astype(np.float32)
    return estimate.astype(np.float64) + (mu[:, None] if b.ndim == 2 else mu)


def _atom_count(model: FrostModel, distinct: int, n_atoms) -> int:
    k = model.n_components
    if n_atoms is None:
        return max(1, min(distinct, k))
    if not isinstance(n_atoms, (int, np.integer)) or not 1 <= n_atoms <= k:
        raise ReconstructionError(f"n_atoms (--atoms): expected an integer in [1, {k}], found {n_atoms!r}")
    return int(n_atoms)


def average_duplicates(positions: np.ndarray, values: np.ndarray):
    """Distinct positions (ascending) and the mean value of the samples at each; (u,), (u, 3)."""
    unique, inverse = np.unique(positions, return_inverse=True)
    sums = np.zeros((unique.size, values.shape[1]))
    np.add.at(sums, inverse, values)
    return unique, sums / np.bincount(inverse, minlength=unique.size)[:, None]


def _check_samples(model: FrostModel, positions, values):
    positions = np.asarray(positions)
    values = np.asarray(values, dtype=np.float64)
    if positions.ndim != 1 or positions.size == 0 or values.shape != (positions.size, 3):
        raise ReconstructionError(
            f"samples: expected positions (l,) with l >= 1 and values (l, 3), found {positions.shape} and {values.shape}")
    if not np.issubdtype(positions.dtype, np.integer):
        raise ReconstructionError(f"samples: positions must be integers, found {positions.dtype}")
    bad = (positions < 0) | (positions >= model.grid.n_valid)
    if bad.any():
        raise ReconstructionError(f"samples: position {int(positions[bad][0])} is not a valid cell (expected 0..{model.grid.n_valid - 1})")
    check_values(values, lambda i: f"sample {i}")
    return positions.astype(np.int64), values


def check_values(values: np.ndarray, where, columns=("channel r", "channel g", "channel b"),
                 expected: str = "a finite BRDF >= 0 (1/sr)") -> None:
    """Refuse NaN, inf and negative values (l, 3), naming the first offending sample (``where(i)``),
    its column (``columns``: one name per column) and what a value must be (``expected``: the
    samples' standard deviations are checked here too, and are no BRDF)."""
    for test, what in ((np.isnan, "NaN"), (np.isinf, "infinite"), (lambda v: v < 0, "negative")):
        bad = np.argwhere(test(values))
        if bad.size:
            i, c = bad[0]
            raise ReconstructionError(f"{where(i)}: {what} value {values[i, c]} in {columns[c]}; expected {expected}")
