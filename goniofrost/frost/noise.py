"""The noise model: the representation error of unseen materials, learned by cross-validation.

sigma_c^2 (n_valid,) is the mean square, per cell, of the held-out training materials' residual
beyond each inner fold's dictionary, smoothed over the grid; every fold comes from the t x t Gram
matrix of the mapped training data. The algebra: docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from goniofrost.core.grid import MerlGrid

# Inner folds of the training materials (fewer when there are fewer materials).
FOLDS = 10
# Width of the Gaussian that smooths sigma_c^2 over the grid, as a fraction of each index
# axis (theta_h, theta_d, phi_d): 1.5 x 1.5 x 3 cells at full resolution. The square-root
# spacing of theta_h makes it finer in angle near the specular peak, where errors change fast.
SMOOTH_FRACTION = 1.0 / 60.0
# Rows of X per chunk of the residual pass (a (rows, t) float32 product).
CHUNK_ROWS = 1 << 15
# Eigenvalues below this fraction of the largest are treated as zero (as in training).
RANK_TOL = 1e-12


@dataclass
class InnerFold:
    """One inner fold, all from the Gram matrix (t training columns, |A| + |B| = t).

    held: int64 (|B|,) held-out columns; train: int64 (|A|,) the fold's training columns;
    projector: float64 (t, K_f): J_A V_f, so that D_f = X @ projector;
    singular_values: float64 (K_f,) S_f; centring: float64 (t, |B|) E_B (X @ E_B = the
    held-out columns minus the fold's mean); true_coefficients: float64 (K_f, |B|), the
    held-out columns' coefficients on D_f; residual_norms: float64 (|B|,) ||X m_b||^2, the
    squared norm (over all cells) of what D_f cannot represent; residual_map: float64 (t, |B|) M_B.
    """

    held: np.ndarray
    train: np.ndarray
    projector: np.ndarray
    singular_values: np.ndarray
    centring: np.ndarray
    true_coefficients: np.ndarray
    residual_norms: np.ndarray
    residual_map: np.ndarray

    @property
    def n_train_columns(self) -> int:
        """|A|, the fold's number of training columns (its prior variance is 1 / |A|)."""
        return int(self.train.size)


def fold_of_material(n_materials: int, folds: int = FOLDS) -> np.ndarray:
    """int64 (n_materials,): the inner fold of every material (i mod F, F <= n_materials)."""
    return np.arange(n_materials, dtype=np.int64) % min(folds, n_materials)


def inner_folds(gram: np.ndarray, n_materials: int, k: int, folds: int = FOLDS) -> list[InnerFold]:
    """The F inner folds of a Gram matrix of t = 3 * n_materials columns (material-major)."""
    gram = np.asarray(gram, dtype=np.float64)
    t = gram.shape[0]
    fold_col = np.repeat(fold_of_material(n_materials, folds), 3)
    return [_fold(gram, np.flatnonzero(fold_col != f), np.flatnonzero(fold_col == f), k, t)
            for f in range(int(fold_col.max()) + 1)]


def _fold(gram, train, held, k, t) -> InnerFold:
    a = train.size
    centred = gram[np.ix_(train, train)]
    centred = centred - centred.mean(axis=0)[None, :]
    centred = centred - centred.mean(axis=1)[:, None]
    evals, evecs = np.linalg.eigh(centred)
    order = np.argsort(evals)[::-1]
    evals, evecs = evals[order], evecs[:, order]
    rank = int(np.sum(evals > RANK_TOL * max(evals[0], 0.0))) if evals[0] > 0 else 0
    kf = max(1, min(k, rank))
    v, s = evecs[:, :kf], np.sqrt(np.maximum(evals[:kf], 1e-300))
    centring = np.zeros((t, held.size))
    centring[held, np.arange(held.size)] = 1.0
    centring[train, :] -= 1.0 / a
    coef = (v / s).T @ (gram[train, :] @ centring)           # on the orthonormal atoms U_f
    residual_map = centring.copy()
    residual_map[train, :] -= (v / s) @ coef
    projector = np.zeros((t, kf))
    projector[train] = v
    norms = np.einsum("ij,ij->j", residual_map, gram @ residual_map)
    return InnerFold(held, train, projector, s, centring, coef / s[:, None], np.maximum(norms, 0.0), residual_map)


def representation_variance(mapped: np.ndarray, folds: list[InnerFold], missing: dict | None = None) -> np.ndarray:
    """float64 (n,): every cell's mean squared held-out residual over all t training columns.

    mapped: the centred mapped training data X, float32 (n, t). One chunked pass over X.
    missing: {material: bool (n,)} cells a material has no data for (``rgl:PATH``): its residual
    there is left out of the cell's mean (a cell nobody measured gets 0).
    """
    n, t = mapped.shape
    m = np.zeros((t, t), dtype=np.float32)
    for fold in folds:
        m[:, fold.held] = fold.residual_map
    out = np.empty(n)
    for start in range(0, n, CHUNK_ROWS):
        block = mapped[start:start + CHUNK_ROWS] @ m
        count = np.full(block.shape[0], float(t))
        for j, mask in (missing or {}).items():
            rows = mask[start:start + CHUNK_ROWS]
            block[rows, 3 * j:3 * j + 3] = 0.0
            count -= 3.0 * rows
        out[start:start + CHUNK_ROWS] = np.einsum("ij,ij->i", block, block, dtype=np.float64) / np.maximum(count, 1.0)
    return out


def smooth_on_grid(values: np.ndarray, grid: MerlGrid, fraction: float = SMOOTH_FRACTION) -> np.ndarray:
    """float64 (n_valid,): ``values`` on the valid cells smoothed by a normalised Gaussian over
    the grid indices (invalid cells carry no weight; phi_d wraps around, phi_d ~ phi_d + pi)."""
    full, weight = np.zeros(grid.size), np.zeros(grid.size)
    full[grid.valid_cells], weight[grid.valid_cells] = values, 1.0
    sigma = [fraction * n for n in grid.shape]
    modes = ("nearest", "nearest", "wrap")
    num = gaussian_filter(full.reshape(grid.shape), sigma, mode=modes, truncate=3.0)
    den = gaussian_filter(weight.reshape(grid.shape), sigma, mode=modes, truncate=3.0)
    return (num.reshape(-1) / np.maximum(den.reshape(-1), 1e-12))[grid.valid_cells]
