"""The sequential scene-aware design: re-plan the remaining picks at this material's posterior.

``continue_design`` takes the image sensitivity g at the posterior mean of the samples so far and
continues the greedy design from those picks under the weights u g^p. The algebra:
docs/explanations/scene-aware-design.md.
"""
from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from goniofrost.frost.bayes_selection import GreedyDesign, greedy_design
from goniofrost.frost.posterior import cell_noise, design_scale, fit, prior_variance
from goniofrost.frost.reconstruction import reconstruct_mapped
from goniofrost.frost.usage_design import (is_uniform, linear_usage, rotate, scene_matrix, sensitivity,
                                           sensitivity_power)


def posterior_mean(model, picked, mapped) -> np.ndarray:
    """The posterior mean of the mapped BRDF, L_hat = mu + D s_hat, float64 (n_valid, c), from
    samples at rows ``picked`` (int (l,)) with mapped values ``mapped`` ((l, c) or (l,),
    ``model.to_log`` of the measured values: mu not subtracted), under the model's cell noise."""
    picked = np.asarray(picked, dtype=np.int64)
    mu = np.asarray(model.mean, dtype=np.float64)
    b = np.asarray(mapped, dtype=np.float64).reshape(picked.size, -1) - mu[picked, None]
    noise = cell_noise(model)
    s2 = np.asarray(model.singular_values, np.float64) ** 2
    post = fit(model.dictionary[picked], noise[picked], prior_variance(model), b, s2, float(noise.sum()), noise.size)
    return reconstruct_mapped(model, post)


def continue_design(model, usage: np.ndarray, picked, mapped, m: int, power: float | None = None,
                    threads: int | None = None, candidates: np.ndarray | None = None) -> GreedyDesign:
    """The next m - l picks of the scene's design after the l cells ``picked`` (int (l,), rows of
    the model) were measured with mapped values ``mapped`` ((l, c), ``model.to_log``).

    The weights are u g^p with g at this material's posterior mean (``usage`` (n_valid,) sum 1; a
    uniform map is the plain design's continuation); ``power`` p defaults to
    ``usage_design.sensitivity_power(m)``; no prior spread. Picked cells are not picked again;
    ``candidates``: bool (n_valid,), the cells allowed (default all). Returns the continuation's
    GreedyDesign (its ``rows``: the m - l new rows in pick order).
    """
    picked = np.asarray(picked, dtype=np.int64)
    n = model.grid.n_valid
    if not 0 < picked.size < m:
        raise ValueError(f"continue_design: expected 0 < {picked.size} picks so far < m = {m}")
    usage = np.asarray(usage, dtype=np.float64)
    power = sensitivity_power(m) if power is None else power
    if is_uniform(usage) or power == 0:
        weights = usage
    else:
        level = posterior_mean(model, picked, mapped).mean(axis=1)
        weights = linear_usage(usage, sensitivity(level, model.reference, model.weight, model.eps), power)
    noise = cell_noise(model) * design_scale(model)  # what the design assumes (bayes_selection)
    d = np.asarray(model.dictionary[picked], dtype=np.float64)
    precision = d.T @ (d / noise[picked, None])
    precision[np.diag_indices_from(precision)] += 1.0 / prior_variance(model)
    covariance = np.linalg.inv(precision)
    chol = np.linalg.cholesky(0.5 * (covariance + covariance.T))  # Sigma_l = C C^T
    with threadpool_limits(limits=1, user_api="blas"):  # 1.5 s -> 0.1 s for the scene matrix at load 5
        lam, q = np.linalg.eigh(chol.T @ scene_matrix(model.dictionary, weights) @ chol)
        rotated = rotate(model.dictionary, chol @ q)
    open_ = np.ones(n, dtype=bool) if candidates is None else np.array(candidates, dtype=bool)
    if open_.shape != (n,):
        raise ValueError(f"continue_design: candidates must be a bool mask of the {n} valid cells, found shape {open_.shape}")
    open_[picked] = False
    rows = np.flatnonzero(open_)
    return greedy_design(rotated, np.clip(lam, 0.0, None), np.ones(lam.size), noise, m - picked.size, rows=rows,
                         threads=threads)
