"""FROST sample selection: simultaneous OMP over the dictionary's pseudo-inverse columns.

Paper Algorithm 1 (DESIGN.md "FROST selection"). With k atoms, U_k and S_k from the model:

* Q = S_k^-1 U_k^T (k x n_valid) = S_k^-2 D_k^T, columns normalised to unit l2 norm;
* Y = V_k^T (k x t): all t training columns (``y_form="all"``, the MMV form) or the first
  t = m columns as in the authors' MATLAB code (``y_form="firstm"``);
* SOMP: R = Y; each step picks j maximising ||R^T q_j||_1 (lowest index on ties) and sets
  R = Y minus its projection on the span of the chosen columns.

Fast exact form used here ("fast form" of DESIGN.md). With B (k x i) an orthonormal basis of
the chosen columns (classical Gram-Schmidt applied twice), R = (I - B B^T) Y changes by one
rank-1 product per step, and so does the score matrix C = Q^T R (n x t): C -= (Q^T b)(R^T b)^T.
C is kept in float32 and updated in place block by block (gemv, BLAS sger, scores) so a step
costs one pass over Q and C (over C alone once R is well conditioned, Q^T b = C z with R z = b);
near-ties are re-scored exactly in float64. The picks equal the
textbook algorithm's (tests/test_frost.py compares them with an lstsq-based SOMP).
Memory: C is n x t float32: 89 MB for m = 20 with y_form "firstm" at full size, 1.75 GB
with y_form "all" (t = 393).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from concurrent.futures import ThreadPoolExecutor

from scipy.linalg import blas
from threadpoolctl import threadpool_limits

from .errors import GoniofrostError
from .grid import MerlGrid
from .model import FrostModel

Y_FORMS = ("all", "firstm")
# Measured (benchmarks/frost_accuracy.py, full grid, 20 held-out materials): the first-m form
# reconstructs as well as the all-columns form (0.110 vs 0.111 at m=10, 0.063 vs 0.065 at
# m=20, 0.040 vs 0.040 at m=40) and its C is t = m columns wide instead of 393.
DEFAULT_Y_FORM = "firstm"
# Scores within this fraction of the largest first score below the float32 maximum are
# re-scored exactly in float64 (float32 rounding of the updated C is far smaller).
RESCORE_MARGIN = 1e-4
# Bytes of C per block of the score updates (measured at full size, t = 20 and 60: 1 MB is
# as fast as or faster than 256 KB ... 2 MB).
BLOCK_BYTES = 1 << 20
# Steps may take Q^T b from C (see _ScoreState) once ||Y||_2 / sigma_min(R) <= this bound on
# the growth of C's float32 error (measured: Q-pass error ~2e-7 of the first top score at full
# size, so the worst case stays below RESCORE_MARGIN; from the first step, where the ratio is
# ~1e4, the error reached 8.5e-5).
CZ_MAX_GROWTH = 100.0


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
    y_form: "firstm" (default: the first m training columns, as the authors' code) or "all"
        (every training column; same accuracy here, ~20x the memory and time at full size).
    k: atoms used for Q and Y; default m (paper), or all K model atoms with max_error
        (then "firstm" uses the first k training columns, m being unknown in advance).
    Returns a Selection; raises SelectionError for bad options or too few candidate cells.
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
    # Per-block BLAS calls are small: OpenBLAS's own threads only add overhead (badly so on
    # a shared machine); _ScoreState runs two Python threads of single-threaded BLAS instead.
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(max_workers=2) as pool:
        return _somp_steps(_ScoreState(q, y, pool), q, y, limit, max_error)


def _somp_steps(state, q, y, limit, max_error):
    """The SOMP loop: pick, orthonormalise, update; stop at ``limit`` picks or max_error."""
    k = q.shape[1]
    y_norm = np.linalg.norm(y)
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
        picked.append(j)
        # The residual after this pick is known from R before C is updated: skip the pass
        # over C after the last pick.
        residual = float(np.linalg.norm(state.r - np.outer(b, b @ state.r)) / y_norm)
        done = len(picked) == limit or (max_error is not None and residual <= max_error)
        state.add(j, b, update_scores=not done)
        residuals.append(float(np.linalg.norm(state.r) / y_norm))
        if done:
            break
    return np.array(picked, dtype=np.int64), np.array(residuals)


def _orthonormal_step(basis: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v orthogonalised against the basis columns (Gram-Schmidt twice) and normalised."""
    for _ in range(2):
        v = v - basis @ (basis.T @ v)
    return v / np.linalg.norm(v)


class _ScoreState:
    """The residual R (k, t) float64 and the score matrix C = Q^T R (n, t) float32.

    Adding an orthonormal basis vector b changes R by -b (b^T R) and C by the rank-1 term
    -(Q^T b)(R^T b)^T. C is stored transposed in blocks of ``rows`` cells, ``c[i]`` (t, rows)
    holding cells i*rows ... i*rows + rows - 1 (the last block zero-padded): the rank-1 update
    of a block is then t long axpys (BLAS ``sger`` on the Fortran-ordered view) instead of
    ``rows`` short ones, about half the CPU time of the cell-major layout at t = 20. One step
    is one pass over Q^T and C: v = Q_blk b (gemv), C_blk -= u v^T (sger, in place) and the
    scores 1^T |C_blk| (gemv), the blocks (~1 MB, in cache) shared by two threads (BLAS and
    numpy release the GIL); once R is well conditioned v = C_blk z instead (``_from_c``). float32 rounding in C is harmless: the best cells within a small
    margin are re-scored exactly in float64 from Q and R.
    """

    def __init__(self, q: np.ndarray, y: np.ndarray, pool: ThreadPoolExecutor) -> None:
        self.q, self.r, self.pool = q, y.copy(), pool
        n, t = q.shape[0], y.shape[1]
        # Q^T b from C (square Y only: then every new direction b is in range(R)).
        self.cz = "wait" if y.shape[0] == t else "off"
        self.y_norm2 = float(np.linalg.norm(y, 2))
        self.rows = max(256, BLOCK_BYTES // (4 * t))  # ~1 MB of C per block
        self.starts = list(range(0, n, self.rows))
        self.c = np.empty((len(self.starts), t, self.rows), dtype=np.float32)
        self.c[-1] = 0.0  # the padding of the last block stays 0 (its v entries are 0)
        self.picked: list[int] = []  # their scores are set to -1 after each pass
        self.scores = np.empty(n, dtype=np.float32)
        self._run_blocks(np.ascontiguousarray(self.r.T, dtype=np.float32))  # C = Q^T R
        self.scale = float(self.scores.max())

    def add(self, j: int, b: np.ndarray, update_scores: bool = True) -> None:
        """Account for the new orthonormal basis vector b (k,) of picked row j.

        update_scores=False (the last pick) updates R only: C and the scores are not needed.
        """
        u = b @ self.r  # (t,) = R^T b
        z = self._from_c(b) if update_scores else None
        self.r -= np.outer(b, u)
        self.picked.append(j)
        if update_scores:
            first = ("c", z) if z is not None else ("q", b)
            self._run_blocks((first[0], first[1].astype(np.float32), u.astype(np.float32)))
            self.scores[self.picked] = -1.0

    def _from_c(self, b: np.ndarray) -> np.ndarray | None:
        """z with R z = b (R before this pick), so that Q^T b = C z; None: use the Q pass.

        With Y square, R = (I - B B^T) Y has range = the complement of the basis B, which
        holds b: the pass then reads C only (in cache) instead of Q and C. C's float32 error
        is carried along: C_new = C (I - z u^T), and over consecutive such steps from R_s on
        its growth is at most 1 + ||Y||_2 / sigma_min(R_s) (the products telescope to R_s^+
        R_now on the row space of R_s and leave its complement alone). So these steps start
        once that ratio is <= CZ_MAX_GROWTH (it only decreases) and, once stopped, stay
        stopped.
        """
        if self.cz == "off":
            return None
        rank = self.r.shape[0] - len(self.picked)
        left, sv, right = np.linalg.svd(self.r, full_matrices=False)
        z = None
        if rank > 0 and sv[rank - 1] * CZ_MAX_GROWTH >= self.y_norm2:
            z = right[:rank].T @ ((left[:, :rank].T @ b) / sv[:rank])
            if np.linalg.norm(self.r @ z - b) > 1e-9:
                z = None
        if z is None:
            self.cz = "off" if self.cz == "on" or rank <= 0 else self.cz
        else:
            self.cz = "on"
        return z

    def _run_blocks(self, update) -> None:
        """Run ``_blocks`` on two threads: update is R32^T (t, k) to fill C, or ("q", b, u) /
        ("c", z, u) to update it with v = Q^T b or C z."""
        half = (len(self.starts) + 1) // 2
        parts = [range(half), range(half, len(self.starts))]
        for future in [self.pool.submit(self._blocks, part, update) for part in parts if len(part)]:
            future.result()

    def _blocks(self, blocks, update) -> None:
        t, rows, n = self.c.shape[1], self.rows, self.q.shape[0]
        ones = np.ones(t, dtype=np.float32)
        tmp = np.empty((t, rows), dtype=np.float32)
        v = np.zeros(rows, dtype=np.float32)
        for i in blocks:
            start = self.starts[i]
            size = min(rows, n - start)
            c = self.c[i]
            q = self.q[start:start + size]
            if isinstance(update, np.ndarray):
                np.matmul(update, q.T, out=c[:, :size])  # (t, k) @ (k, size)
            else:
                if update[0] == "q":
                    np.matmul(q, update[1], out=v[:size])  # v = Q_blk b; v[size:] stays 0
                else:
                    np.matmul(update[1], c, out=v)  # v = C_blk z (0 on the padding)
                out = blas.sger(-1.0, v, update[2], a=c.T, overwrite_a=1)  # c -= u v^T in place
                if not np.shares_memory(out, c):  # (only if a wrapper ever copied)
                    c[...] = out.T
            np.abs(c[:, :size], out=tmp[:, :size])
            np.matmul(ones, tmp[:, :size], out=self.scores[start:start + size])

    def best_column(self) -> int:
        """Row maximising ||R^T q_j||_1 among open rows (lowest on ties); -1 if all ~0."""
        scores = self.scores  # picked rows hold -1
        top = float(scores.max())
        if top <= 1e-5 * self.scale:  # nothing left above float32 noise
            return -1
        # float32 near-ties are settled in float64, lowest index first.
        close = np.flatnonzero(scores >= top - RESCORE_MARGIN * self.scale)
        return int(close[np.argmax(_scores64(self.q[close], self.r))])


def _scores64(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.abs(rows.astype(np.float64) @ r).sum(axis=1)
