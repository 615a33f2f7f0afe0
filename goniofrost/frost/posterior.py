"""The Bayesian reading of the FROST model: prior, noise, posterior, leave-one-out residuals.

L - mu = D s + e, s ~ N(0, I / t), e_c ~ N(0, sigma_c^2); given samples b at cells l with
W = diag(1 / sigma_l^2): Sigma = (t I + D_l^T W D_l)^-1, s_hat = Sigma D_l^T W b. Leave-one-out
residuals: e_i = (b_i - d_i^T s_hat) / (1 - h_i), h_i = w_i d_i^T Sigma d_i, of variance
sigma_i^2 + d_i^T Sigma d_i / (1 - h_i). More: docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

# Noise of a model without a learned noise model (format version 1): sigma^2 = SCALAR_ETA / t
# per cell, i.e. the posterior mean is ridge regression over all K atoms with eta = 10 (the
# setting the nested validation on training materials chose in every fold).
SCALAR_ETA = 10.0
# Rows of D per chunk of the predictive-variance pass (bounds the temporary (rows, K) arrays).
CHUNK_ROWS = 1 << 15


def prior_variance(model) -> np.ndarray:
    """float64 (K,): the prior variance 1/t of every coefficient."""
    return np.full(model.n_components, 1.0 / model.n_signals)


def cell_noise(model) -> np.ndarray:
    """float64 (n_valid,): sigma_c^2, the model noise of every valid cell (mapped domain).

    The learned per-cell variance of a format-2 model, else the scalar SCALAR_ETA / t.
    """
    stored = getattr(model, "noise_variance", None)
    if stored is not None:
        return np.asarray(stored, dtype=np.float64)
    return np.full(model.grid.n_valid, SCALAR_ETA / model.n_signals)


def design_scale(model) -> float:
    """The factor on sigma_c^2 the Bayesian design assumes (chosen at training, see
    calibration.py; 1 without a learned noise model)."""
    return float((getattr(model, "noise", None) or {}).get("design_scale", 1.0))


def log_map_variance(values, sigmas, weight, eps: float) -> np.ndarray:
    """Variance of log(w x + eps) from a sample's standard deviation (first order).

    values, sigmas: (l, c) BRDF and its standard deviation in 1/sr; weight: (l,) w.
    Returns float64 (l, c): (w sigma / (w x + eps))^2.
    """
    w = np.asarray(weight, dtype=np.float64)[:, None]
    x = np.asarray(values, dtype=np.float64)
    return (w * np.asarray(sigmas, dtype=np.float64) / (w * x + eps)) ** 2


@dataclass
class Posterior:
    """The posterior of the coefficients for one set of samples (c columns: channels/materials).

    coefficients: float64 (K, c), s_hat per column.
    covariances: float64 (g, K, K), Sigma of each noise group (columns with the same noise share one).
    group: int64 (c,), the covariance index of every column.
    loo_residuals: float64 (l, c), closed-form leave-one-out residuals at the sampled cells.
    loo_variance: float64 (l, c), their variance under the model.
    design_error: float64 (c,), mean predictive variance over all valid cells (see module doc).
    """

    coefficients: np.ndarray
    covariances: np.ndarray
    group: np.ndarray
    loo_residuals: np.ndarray
    loo_variance: np.ndarray
    design_error: np.ndarray


def fit(rows: np.ndarray, noise: np.ndarray, prior_var: np.ndarray, b: np.ndarray,
        s2: np.ndarray, noise_total: float, n_cells: int) -> Posterior:
    """The posterior from samples.

    rows: (l, K) dictionary rows of the sampled cells; noise: (l,) or (l, c) sigma_i^2;
    prior_var: (K,); b: (l, c) mapped samples minus mu; s2: (K,) S^2 (D^T D), or (K, K) a
    scene's M = D^T diag(u) D (``usage_design``; the design error is then trace(M Sigma) +
    noise_total with noise_total = sum_c u_c sigma_c^2 and n_cells = 1);
    noise_total: sum of sigma_c^2 over all n_cells valid cells.
    """
    rows = np.asarray(rows, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    noise = np.broadcast_to(np.asarray(noise, dtype=np.float64).reshape(b.shape[0], -1), b.shape)
    groups, group = np.unique(noise, axis=1, return_inverse=True)
    group = np.asarray(group).reshape(-1)
    k, c = rows.shape[1], b.shape[1]
    coefficients, covariances = np.empty((k, c)), np.empty((groups.shape[1], k, k))
    residuals, variance, design = np.empty_like(b), np.empty_like(b), np.empty(c)
    for gi in range(groups.shape[1]):
        cols = np.flatnonzero(group == gi)
        sig2 = groups[:, gi]
        cov = _covariance(rows, 1.0 / sig2, prior_var)
        s = cov @ (rows.T @ (b[:, cols] / sig2[:, None]))
        q = np.einsum("ij,jk,ik->i", rows, cov, rows)
        h = np.minimum(q / sig2, 1.0 - 1e-12)  # h < 1 always (the prior); guard rounding
        residuals[:, cols] = (b[:, cols] - rows @ s) / (1.0 - h)[:, None]
        variance[:, cols] = (sig2 + q / (1.0 - h))[:, None]
        coefficients[:, cols], covariances[gi] = s, cov
        design[cols] = (error_trace(s2, cov) + noise_total) / n_cells
    return Posterior(coefficients, covariances, group, residuals, variance, design)


def error_trace(weights: np.ndarray, covariance: np.ndarray) -> float:
    """trace(W Sigma): the expected squared error the coefficients' covariance Sigma (K, K) leaves,
    weighted by W: (K,) the diagonal S^2 (or a scene's Lambda), or (K, K) a scene's M."""
    if np.ndim(weights) == 2:
        return float(np.sum(weights * covariance))
    return float(np.sum(weights * np.diag(covariance)))


def _covariance(rows: np.ndarray, w: np.ndarray, prior_var: np.ndarray) -> np.ndarray:
    """Sigma = (diag(1 / prior_var) + rows^T W rows)^-1, symmetric, via Cholesky."""
    precision = rows.T @ (rows * w[:, None])
    precision[np.diag_indices_from(precision)] += 1.0 / prior_var
    chol = np.linalg.cholesky(precision)
    inv_chol = np.linalg.solve(chol, np.eye(chol.shape[0]))
    return inv_chol.T @ inv_chol


def mean_and_variance(dictionary, mean, post: Posterior, columns=None):
    """Posterior mean D s_hat + mu and d_c^T Sigma d_c over every row of ``dictionary``.

    dictionary: float32 (n, K); mean: (n,) mu; post: the Posterior of ``fit``. columns: the
    posterior's columns to evaluate (default all c). Returns (estimate float64 (n, c), variance float64
    (n, u), used int64 (u,)): the mapped estimates (mu added) and d_c^T Sigma d_c for each
    covariance group ``used[j]`` of those columns.

    One chunked pass over D: d^T Sigma d = ||L^T d||^2 with Sigma = L L^T, a sum of squares exact to
    float32 rounding (the Woodbury form subtracts nearly equal float32 numbers).
    """
    cols = np.arange(post.coefficients.shape[1]) if columns is None else np.asarray(columns)
    used = np.unique(post.group[cols])
    factors = [np.linalg.cholesky(post.covariances[g]) for g in used]
    right = np.concatenate([post.coefficients[:, cols]] + factors, axis=1).astype(np.float32)
    n, c, width = dictionary.shape[0], cols.size, factors[0].shape[1]
    estimate, variance = np.empty((n, c)), np.empty((n, used.size))
    mu = np.asarray(mean, dtype=np.float64)
    with threadpool_limits(limits=1, user_api="blas"):  # measured: a second thread only slows it here
        for start in range(0, n, CHUNK_ROWS):
            stop = min(start + CHUNK_ROWS, n)
            block = np.asarray(dictionary[start:stop], dtype=np.float32)
            prod = block @ right
            estimate[start:stop] = prod[:, :c] + mu[start:stop, None]
            for gi in range(used.size):
                part = prod[:, c + gi * width:c + (gi + 1) * width]
                variance[start:stop, gi] = np.einsum("ij,ij->i", part, part)
    return estimate, variance, used


def prequential_errors(rows: np.ndarray, noise: np.ndarray, prior_var: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Standardized one-step-ahead prediction errors of samples taken in order.

    rows: (l, K) dictionary rows of the sampled cells in measurement order; noise: (l,)
    sigma_i^2 (shared by every column); prior_var: (K,); b: (l, c) mapped samples minus mu.
    Returns float64 (l, c): row k is (b_k - d_k^T s_k)^2 / (sigma_k^2 + d_k^T Sigma_k d_k), s_k
    and Sigma_k the posterior of the first k samples (k = 0: the prior), i.e. how well the
    samples so far predicted one that was never fitted (about 1 on average when the model
    describes the material; row 0 is the prior's). Sequential rank-one (Kalman) updates: the
    posterior of the first k samples is exactly ``fit``'s, O(l K^2) in all.
    """
    rows = np.asarray(rows, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    noise = np.broadcast_to(np.asarray(noise, dtype=np.float64).reshape(-1), (rows.shape[0],))
    cov = np.diag(np.asarray(prior_var, dtype=np.float64))
    s = np.zeros((rows.shape[1], b.shape[1]))
    out = np.empty_like(b)
    for k in range(rows.shape[0]):
        d = rows[k]
        cd = cov @ d
        v = float(noise[k] + d @ cd)
        miss = b[k] - d @ s
        out[k] = miss ** 2 / v
        gain = cd / v
        s += np.outer(gain, miss)
        cov -= np.outer(gain, cd)
    return out
