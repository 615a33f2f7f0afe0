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
    k = q.shape[1]
    y_norm = np.linalg.norm(y)
    state = _BoundState(q, y)
    basis = np.zeros((k, 0))
    picked: list[int] = []
    residuals: list[float] = []
    while len(picked) < limit:
        j = state.best_column()
        if j < 0:
            raise SelectionError(
                f"selection: the allowed cells span only {len(picked)} independent directions; "
                "allow more cells or ask for fewer samples")
        b = _orthonormal_step(basis, q[j].astype(np.float64))
        basis = np.column_stack([basis, b])
        state.add(j, b)
        picked.append(j)
        residuals.append(float(np.linalg.norm(state.r) / y_norm))
        if max_error is not None and residuals[-1] <= max_error:
            break
    return np.array(picked, dtype=np.int64), np.array(residuals)


def _orthonormal_step(basis: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v orthogonalised against the basis columns (Gram-Schmidt twice) and normalised."""
    for _ in range(2):
        v = v - basis @ (basis.T @ v)
    return v / np.linalg.norm(v)


class _BoundState:
    """Residual R and per-cell upper bounds on the SOMP scores ||R^T q_j||_1.

    Two exact bounds, the smaller is used:
    * stale + growth: the exact score at the cell's last evaluation plus, for every basis
      vector b_l added since, ||R_(l-1)^T b_l||_1 |b_l^T q_j| (triangle inequality on the
      rank-1 update R_l = R_(l-1) - b_l b_l^T R_(l-1));
    * min(sqrt(t) ||R||_2, sum_t ||r_t||_2) ||P q_j||_2 with ||P q_j||^2 = 1 - ||B^T q_j||^2.
    Each step costs one gemv Q b plus a few passes over n floats, and exact scores only for
    the cells whose bound reaches the best exact score found.
    """

    def __init__(self, q: np.ndarray, y: np.ndarray) -> None:
        self.q, self.r = q, y.copy()
        n = q.shape[0]
        self.h = np.zeros(n, dtype=np.float32)       # ||B^T q_j||^2
        self.growth = np.zeros(n, dtype=np.float32)
        self.stale = _scores32(q, None, self.r)       # exact scores at step 0
        self.open = np.ones(n, dtype=bool)

    def add(self, j: int, b: np.ndarray) -> None:
        """Account for the new orthonormal basis vector b (k,) of picked row j."""
        a = float(np.abs(self.r.T @ b).sum()) * (1 + BOUND_SLACK)
        self.r -= np.outer(b, b @ self.r)
        v = self.q @ b.astype(np.float32)
        self.h += v * v
        np.abs(v, out=v)
        v *= np.float32(a)
        self.growth += v
        self.open[j] = False

    def bounds(self) -> np.ndarray:
        t = self.r.shape[1]
        coef = min(np.sqrt(t) * np.linalg.norm(self.r, 2), np.linalg.norm(self.r, axis=0).sum())
        ub = 1.0 - self.h
        np.maximum(ub, 0.0, out=ub)
        ub += np.float32(BOUND_SLACK)
        np.sqrt(ub, out=ub)
        ub *= np.float32(coef * (1 + BOUND_SLACK))
        np.minimum(ub, (self.stale + self.growth) * np.float32(1 + BOUND_SLACK), out=ub)
        ub[~self.open] = -1.0
        return ub

    def best_column(self) -> int:
        """Row maximising ||R^T q_j||_1 among open rows (lowest on ties); -1 if all ~0."""
        ub = self.bounds()
        n = ub.size
        probe = np.argpartition(ub, -PROBE)[-PROBE:] if n > PROBE else np.arange(n)
        lower = self._refresh(probe).max() * (1 - BOUND_SLACK)
        cand = np.flatnonzero(ub >= lower)
        scores = self._refresh(cand)
        scores[~self.open[cand]] = -1.0
        top = scores.max() if scores.size else -1.0
        if top <= 1e-9 * max(np.linalg.norm(self.r), 1e-300):
            return -1
        # Near-ties in float32 are settled in float64, lowest index first.
        close = cand[scores >= top * (1 - RESCORE_MARGIN)]
        return int(close[np.argmax(_scores64(self.q[close], self.r))])

    def _refresh(self, rows: np.ndarray) -> np.ndarray:
        # Gathering rows costs more than a contiguous pass once many cells are candidates.
        if rows.size > self.q.shape[0] // 3:
            scores = _scores32(self.q, None, self.r)[rows]
        else:
            scores = _scores32(self.q, rows, self.r)
        self.stale[rows] = scores
        self.growth[rows] = 0.0
        return scores


def _scores64(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.abs(rows.astype(np.float64) @ r).sum(axis=1)


def _scores32(q: np.ndarray, rows: np.ndarray | None, r: np.ndarray) -> np.ndarray:
    """||r^T q_j||_1 (float32) for the given rows of q (all when None), blockwise.

    Product, abs and row sum are fused per block so the (rows x t) score matrix never
    leaves the cache.
    """
    r32 = r.astype(np.float32)
    count = q.shape[0] if rows is None else rows.size
    out = np.empty(count, dtype=np.float32)
    for start in range(0, count, BLOCK):
        part = q[start:start + BLOCK] if rows is None else q[rows[start:start + BLOCK]]
        c = part @ r32
        np.abs(c, out=c)
        out[start:start + BLOCK] = c.sum(axis=1)
    return out
