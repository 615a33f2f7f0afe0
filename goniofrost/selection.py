"""FROST sample selection: simultaneous OMP over the dictionary's pseudo-inverse columns.

Paper Algorithm 1 (DESIGN.md "FROST selection"). With k atoms, U_k and S_k from the model:

* Q = S_k^-1 U_k^T (k x n_valid) = S_k^-2 D_k^T, columns normalised to unit l2 norm;
* Y = V_k^T (k x t): all t training columns (``y_form="all"``, the MMV form) or the first
  t = m columns as in the authors' MATLAB code (``y_form="firstm"``);
* SOMP: R = Y; each step picks j maximising ||R^T q_j||_1 (lowest index on ties) and sets
  R = Y minus its projection on the span of the chosen columns.

Fast exact form used here. B (k x i) is an orthonormal basis of the chosen columns
(classical Gram-Schmidt applied twice), so R = (I - B B^T) Y is updated by one rank-1
product per step and the scores C = R^T Q change by the rank-1 term (R^T b)(b^T Q). Rather
than storing C (t x n: 1.75 GB for t = 393 at full size) we prune with an exact upper bound:

    ||R^T q_j||_1 <= min(sqrt(t) ||R||_2, sum_t ||r_t||_2) * ||P q_j||_2,
    ||P q_j||_2^2 = 1 - ||B^T q_j||^2   (kept incrementally: one gemv b^T Q per step),

and evaluate exact scores only for cells whose bound reaches the best exact score of the
cells with the largest bounds. The picks are identical to the textbook algorithm
(tests/test_frost.py compares them with an lstsq-based SOMP).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .errors import GoniofrostError
from .grid import MerlGrid
from .model import FrostModel

Y_FORMS = ("all", "firstm")
DEFAULT_Y_FORM = "all"
# Cells scored per block in a full pass: (block x t) float32 stays in cache.
BLOCK = 4096
# Cells with the largest bounds scored first to get a good lower bound on the best score.
PROBE = 64
# Relative slack on the bound (float32 rounding of Q and h); keeps pruning exact.
BOUND_SLACK = 1e-3
# Scores within this relative margin of the float32 maximum are re-scored in float64.
RESCORE_MARGIN = 1e-4


class SelectionError(GoniofrostError, ValueError):
    """Selection options that cannot be used (m, max_error, candidates, y_form, k)."""


@dataclass
class Selection:
    """The outcome of FROST selection, in pick (= measurement) order.

    positions: int64 (m,) indices into ``grid.valid_cells`` (rows of the model arrays).
    cells: int64 (m,) flat MERL cell indices.
    residuals: float64 (m,) relative residual ||R||_F / ||Y||_F after each pick.
    seconds: wall time of the selection (s). y_form: "all" or "firstm". k: atoms used.
    """

    positions: np.ndarray
    cells: np.ndarray
    residuals: np.ndarray
    seconds: float
    y_form: str
    k: int

    @property
    def m(self) -> int:
        """Number of samples selected."""
        return int(self.positions.size)


def candidate_mask_max_angle(grid: MerlGrid, max_angle_deg: float) -> np.ndarray:
    """bool (n_valid,): True where both theta_i and theta_o of the cell are <= max_angle_deg."""
    w_i, w_o = grid.cell_directions(grid.valid_cells)
    limit = np.cos(np.radians(float(max_angle_deg)))
    return (w_i[:, 2] >= limit) & (w_o[:, 2] >= limit)


def select_cells(model: FrostModel, m: int | None = None, *, max_error: float | None = None,
                 candidates: np.ndarray | None = None, y_form: str = DEFAULT_Y_FORM,
                 k: int | None = None) -> Selection:
    """Pick measurement cells with FROST (SOMP); deterministic.

    m: number of samples; or max_error: stop once ||R||_F / ||Y||_F <= max_error (eq. 8).
    candidates: bool (n_valid,) mask of allowed cells (default all valid cells).
    y_form: "all" (every training column) or "firstm" (the first m columns, authors' code).
    k: atoms used for Q and Y; default m (paper), or all K model atoms with max_error.
    """
    start = time.perf_counter()
    k, limit = _check_options(model, m, max_error, y_form, k)
    pos_of_row, q = _atoms(model, k, candidates, limit)
    y = _training_matrix(model, k, y_form, m if m is not None else k)
    rows, residuals = _somp(q, y, limit, max_error)
    positions = pos_of_row[rows] if pos_of_row is not None else rows
    positions = np.asarray(positions, dtype=np.int64)
    return Selection(positions=positions, cells=model.grid.valid_cells[positions],
                     residuals=residuals, seconds=time.perf_counter() - start,
                     y_form=y_form, k=k)


def _check_options(model, m, max_error, y_form, k) -> tuple[int, int]:
    """Validate; return (k, maximum number of picks)."""
    n_atoms = model.n_components
    if y_form not in Y_FORMS:
        raise SelectionError(f"y_form: expected one of {Y_FORMS}, found {y_form!r}")
    if (m is None) == (max_error is None):
        raise SelectionError("selection: give exactly one of m (--samples) and max_error (--max-error)")
    if m is not None:
        if not isinstance(m, (int, np.integer)) or not 1 <= m <= n_atoms:
            raise SelectionError(f"samples m: expected an integer in [1, {n_atoms}] (the model's components), found {m!r}")
        k = m if k is None else k
        if not isinstance(k, (int, np.integer)) or not m <= k <= n_atoms:
            raise SelectionError(f"k: expected an integer in [m={m}, {n_atoms}], found {k!r}")
        return int(k), int(m)
    if not (isinstance(max_error, (int, float)) and 0.0 < max_error < 1.0):
        raise SelectionError(f"max_error: expected a number in (0, 1), found {max_error!r}")
    k = n_atoms if k is None else k
    if not isinstance(k, (int, np.integer)) or not 1 <= k <= n_atoms:
        raise SelectionError(f"k: expected an integer in [1, {n_atoms}], found {k!r}")
    return int(k), int(k)


def _atoms(model: FrostModel, k: int, candidates, limit: int):
    """Rows of Q^T (n_c, k) float32, normalised; and their positions (None = all valid cells)."""
    d = model.dictionary
    if candidates is None:
        pos = None
        rows = np.array(d[:, :k], dtype=np.float32, order="C")  # a copy: scaled in place below
    else:
        mask = np.asarray(candidates)
        if mask.dtype != bool or mask.shape != (model.grid.n_valid,):
            raise SelectionError(f"candidates: expected a bool mask of shape ({model.grid.n_valid},), found {mask.dtype} {mask.shape}")
        pos = np.flatnonzero(mask)
        if pos.size < limit:
            raise SelectionError(f"candidates: {pos.size} allowed cells, fewer than the {limit} samples asked for")
        rows = np.array(d[pos, :k], dtype=np.float32, order="C")
    s = np.asarray(model.singular_values[:k], dtype=np.float64)
    rows *= (1.0 / s**2).astype(np.float32)
    norms = np.sqrt(np.einsum("ij,ij->i", rows, rows))
    # A zero row (a cell where every training material maps to its mean) can never be picked.
    rows /= np.where(norms > 0, norms, np.inf)[:, None]
    return pos, rows


def _training_matrix(model: FrostModel, k: int, y_form: str, m: int) -> np.ndarray:
    """Y (k x t) float64: V_k^T, all columns or the first m."""
    y = np.asarray(model.coefficients[:k], dtype=np.float64)
    return y if y_form == "all" else y[:, :m].copy()


def _somp(q: np.ndarray, y: np.ndarray, limit: int, max_error: float | None):
    """Run SOMP on rows q (n_c, k) and Y (k, t); return picked rows and residual ratios."""
    n, k = q.shape
    y_norm = np.linalg.norm(y)
    r = y.copy()
    basis = np.zeros((k, 0))
    h = np.zeros(n, dtype=np.float32)  # ||B^T q_j||^2
    picked: list[int] = []
    residuals: list[float] = []
    while len(picked) < limit:
        j = _best_column(q, r, h, picked)
        if j < 0:
            raise SelectionError(
                f"selection: the allowed cells span only {len(picked)} independent directions; "
                "allow more cells or ask for fewer samples")
        b = _orthonormal_step(basis, q[j].astype(np.float64))
        basis = np.column_stack([basis, b])
        r -= np.outer(b, b @ r)
        h += (q @ b.astype(np.float32)) ** 2
        picked.append(j)
        residuals.append(float(np.linalg.norm(r) / y_norm))
        if max_error is not None and residuals[-1] <= max_error:
            break
    return np.array(picked, dtype=np.int64), np.array(residuals)


def _orthonormal_step(basis: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v orthogonalised against the basis columns (Gram-Schmidt twice) and normalised."""
    for _ in range(2):
        v = v - basis @ (basis.T @ v)
    return v / np.linalg.norm(v)


def _best_column(q, r, h, picked) -> int:
    """Index of the row maximising ||r^T q_j||_1 (lowest on ties); -1 if every score is ~0."""
    n, _ = q.shape
    t = r.shape[1]
    col_norms = np.linalg.norm(r, axis=0)
    coef = min(np.sqrt(t) * np.linalg.norm(r, 2), col_norms.sum()) * (1 + BOUND_SLACK)
    bound = coef * np.sqrt(np.maximum(1.0 - h, 0.0) + BOUND_SLACK)
    bound[picked] = -1.0
    probe = np.argpartition(bound, -PROBE)[-PROBE:] if n > PROBE else np.arange(n)
    lower = _scores64(q[probe], r).max() * (1 - BOUND_SLACK)
    cand = np.flatnonzero(bound >= lower)
    scores = _scores32(q, cand, r)
    if cand.size == 0 or scores.max() <= 1e-9 * max(coef, 1e-300):
        return -1
    # Near-ties in float32 are settled in float64, lowest index first.
    close = cand[scores >= scores.max() * (1 - RESCORE_MARGIN)]
    exact = _scores64(q[close], r)
    return int(close[np.argmax(exact)])


def _scores64(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.abs(rows.astype(np.float64) @ r).sum(axis=1)


def _scores32(q: np.ndarray, cand: np.ndarray, r: np.ndarray) -> np.ndarray:
    """||r^T q_j||_1 for rows cand of q, in float32 blocks (fused product, abs and sum)."""
    r32 = r.astype(np.float32)
    out = np.empty(cand.size, dtype=np.float32)
    full = cand.size == q.shape[0]
    for start in range(0, cand.size, BLOCK):
        rows = q[start:start + BLOCK] if full else q[cand[start:start + BLOCK]]
        c = rows @ r32
        np.abs(c, out=c)
        out[start:start + BLOCK] = c.sum(axis=1)
    return out
