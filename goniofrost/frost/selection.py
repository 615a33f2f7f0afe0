"""FROST sample selection: simultaneous OMP over the dictionary's pseudo-inverse columns.

Paper Algorithm 1 (DESIGN.md "FROST selection"): Q = S_k^-1 U_k^T (k x n_valid), columns
normalised; Y = V_k^T: all t training columns (``y_form="all"``) or the first m
(``y_form="firstm"``); SOMP picks j maximising ||R^T q_j||_1 (lowest index on ties) and projects
the chosen columns out of R. DESIGN.md's fast form: the scores C = Q^T R (n x t, float32) take a
rank-1 update per step in ``somp_kernels``, near-ties re-scored in float64, the picks the
textbook's. C is 89 MB for m = 20 with "firstm" at full size, 1.75 GB with "all" (t = 393).
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from goniofrost.frost import somp_kernels as kernels
from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid
from goniofrost.frost.model import FrostModel
from goniofrost.frost.threads import resolve_threads, run_ranges

Y_FORMS = ("all", "firstm")
# Measured (benchmarks/frost_accuracy.py, full grid, 20 held-out materials): the first-m form
# reconstructs as well as the all-columns form (0.110 vs 0.111 at m=10, 0.063 vs 0.065 at
# m=20, 0.040 vs 0.040 at m=40) and its C is t = m columns wide instead of 393.
DEFAULT_Y_FORM = "firstm"
# Scores within this fraction of the largest first score below the float32 maximum are
# re-scored exactly in float64 (float32 rounding of the updated C is far smaller).
RESCORE_MARGIN = 1e-4
# Cells per block of Q and C (the kernels' vector length; measured at full size, t = 20 and
# 60: 256 is as fast as 64 ... 1024 within a few percent).
BLOCK_CELLS = 256
# Steps may take Q^T b from C (see _ScoreState) once ||Y||_2 / sigma_min(R) <= this bound on
# the growth of C's float32 error (measured: Q-pass error ~2e-7 of the first top score at full
# size, so the worst case stays below RESCORE_MARGIN; from the first step, where the ratio is
# ~1e4, the error reached 8.5e-5).
CZ_MAX_GROWTH = 100.0


class SelectionError(GoniofrostError, ValueError):
    """Selection options that cannot be used (m, max_error, candidates, y_form, k)."""


@dataclass
class Selection:
    """The outcome of a selection, in pick (= measurement) order.

    positions: int64 (m,) indices into ``grid.valid_cells`` (rows of the model arrays).
    cells: int64 (m,) flat MERL cell indices.
    residuals: float64 (m,) after each pick: FROST's relative residual ||R||_F / ||Y||_F, or
        for the Bayesian selector the predicted error of a typical material.
    seconds: wall time of the selection (s). y_form: "all" or "firstm" (FROST; "" for bayes).
    k: atoms used. selector: "frost" (SOMP) or "bayes" (A-optimal design).
    pick_seconds: float64 (m,) wall time from the start to each pick (bayes), else None.
    prior_spread: the prior spread t a scene-aware design's weights were made with (its last phase's
        with max_error; ``usage_design.design_weights``), else None.
    sensitivity_power: the power p a scene-aware design's weights used (its last phase's with
        max_error; ``usage_design.scene_power`` unless given), else None.
    design_key: the key (p, largest t, F[, a]; ``usage_design.design_key``) of a scene-aware
        design's weights and of the calibration its predicted errors used (its last phase's with
        max_error), else None.
    bounds: float64 (m,) the bayes selector's typical material's calibrated bound after each pick
        at the confidence ``select_bayes`` was given (what a capture stops on), else None.
    """

    positions: np.ndarray
    cells: np.ndarray
    residuals: np.ndarray
    seconds: float
    y_form: str
    k: int
    selector: str = "frost"
    bounds: np.ndarray | None = None
    pick_seconds: np.ndarray | None = None
    prior_spread: float | None = None
    sensitivity_power: float | None = None
    design_key: tuple | None = None

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
                 k: int | None = None, threads: int | None = None) -> Selection:
    """Pick measurement cells with FROST (SOMP); deterministic.

    m: number of samples; or max_error: stop once ||R||_F / ||Y||_F <= max_error (eq. 8).
    candidates: bool (n_valid,) mask of allowed cells (default all valid cells).
    y_form: "firstm" (default: the first m training columns, as the authors' code) or "all"
        (every training column; same accuracy here, ~20x the memory and time at full size).
    k: atoms used for Q and Y; default m (paper), or all K model atoms with max_error
        (then "firstm" uses the first k training columns, m being unknown in advance).
    threads: threads sharing the blocks of each pass (default: the cores this process may use;
        the passes are memory-bound, two saturate 2 cores); the picks do not depend on it.
    Returns a Selection; raises SelectionError for bad options or too few candidate cells.
    """
    start = time.perf_counter()
    k, limit = _check_options(model, m, max_error, y_form, k)
    threads = resolve_threads(threads)
    pos_of_row, qb, n = _atoms(model, k, candidates, limit, threads)
    y = _training_matrix(model, k, y_form, m if m is not None else k)
    rows, residuals = _somp(qb, n, y, limit, max_error, threads)
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
            raise SelectionError(f"samples m (--samples): expected an integer in [1, {n_atoms}] (the model's components), found {m!r}")
        k = m if k is None else k
        if not isinstance(k, (int, np.integer)) or not m <= k <= n_atoms:
            raise SelectionError(f"k (--atoms): expected an integer in [m={m}, {n_atoms}], found {k!r}")
        return int(k), int(m)
    if not (isinstance(max_error, (int, float)) and 0.0 < max_error < 1.0):
        raise SelectionError(f"max_error (--max-error): expected a number in (0, 1), found {max_error!r}")
    k = n_atoms if k is None else k
    if not isinstance(k, (int, np.integer)) or not 1 <= k <= n_atoms:
        raise SelectionError(f"k (--atoms): expected an integer in [1, {n_atoms}], found {k!r}")
    return int(k), int(k)


def _atoms(model: FrostModel, k: int, candidates, limit: int, threads: int):
    """Q packed for the kernels: (positions or None for all valid cells, qb, n_c).

    qb: float32 (ceil(n_c / BLOCK_CELLS), k, BLOCK_CELLS), qb[b, :, r] the unit-norm atom
    S_k^-2 D_k[cell] of candidate cell b * BLOCK_CELLS + r (zero padding past n_c).
    """
    d = np.ascontiguousarray(model.dictionary, dtype=np.float32)  # no copy of a model's memmap
    if candidates is None:
        pos, rows = None, np.arange(model.grid.n_valid, dtype=np.int64)
    else:
        mask = np.asarray(candidates)
        if mask.dtype != bool or mask.shape != (model.grid.n_valid,):
            raise SelectionError(f"candidates: expected a bool mask of shape ({model.grid.n_valid},), found {mask.dtype} {mask.shape}")
        pos = rows = np.flatnonzero(mask)
        if pos.size < limit:
            raise SelectionError(f"candidates: {pos.size} allowed cells, fewer than the {limit} samples asked for")
    inv_s2 = 1.0 / np.asarray(model.singular_values[:k], dtype=np.float64) ** 2
    qb = np.empty((-(-rows.size // BLOCK_CELLS), k, BLOCK_CELLS), dtype=np.float32)
    # A zero atom (a cell where every training material maps to its mean) is never picked.
    _in_threads(kernels.pack_atoms, qb.shape[0], threads, d, rows, k, inv_s2, qb)
    return pos, qb, rows.size


def _in_threads(kernel, n_blocks: int, threads: int, *args, pool=None) -> None:
    """Run kernel(*args, b0, b1) on contiguous ranges of the n_blocks blocks shared by
    ``threads`` threads (those of ``pool`` if given)."""
    run_ranges(kernel, n_blocks, threads, *args, pool=pool)


def _training_matrix(model: FrostModel, k: int, y_form: str, m: int) -> np.ndarray:
    """Y (k x t) float64: V_k^T, all columns or the first m."""
    y = np.asarray(model.coefficients[:k], dtype=np.float64)
    return y if y_form == "all" else y[:, :m].copy()


def _somp(qb: np.ndarray, n: int, y: np.ndarray, limit: int, max_error: float | None, threads: int):
    """Run SOMP on the packed atoms qb of n cells and Y (k, t); return picked rows and residual ratios."""
    # The batched matmul that fills C runs in our threads: BLAS's own threads would only
    # compete with them.
    # One pool of threads for every pass of the selection.
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(max_workers=threads) as pool:
        return _somp_steps(_ScoreState(qb, n, y, threads, pool), y, limit, max_error)


def _somp_steps(state, y, limit, max_error):
    """The SOMP loop: pick, orthonormalise, update; stop at ``limit`` picks or max_error."""
    y_norm = np.linalg.norm(y)
    basis = np.zeros((y.shape[0], 0))
    picked: list[int] = []
    residuals: list[float] = []
    while len(picked) < limit:
        j = state.best_column()
        if j < 0:
            raise SelectionError(
                f"selection: the allowed cells span only {len(picked)} independent directions; "
                "allow more cells or ask for fewer samples")
        b = _orthonormal_step(basis, state.atoms(j).astype(np.float64))
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
    -(Q^T b)(R^T b)^T. C is stored like Q in blocks of BLOCK_CELLS cells, cb[b, :, r] the row
    of cell b * BLOCK_CELLS + r. One step is one fused pass of a compiled kernel over the
    blocks (somp_kernels): v = Q_blk b, C_blk -= u v^T and the scores 1^T |C_blk|, the
    blocks split among ``threads`` threads; once R is well conditioned v = C_blk z instead
    (``_from_c``), so the pass reads C only. float32 rounding in C is harmless: the best
    cells within a small margin are re-scored exactly in float64 from Q and R.
    """

    def __init__(self, qb: np.ndarray, n: int, y: np.ndarray, threads: int, pool=None) -> None:
        self.qb, self.n, self.r, self.threads, self.pool = qb, n, y.copy(), threads, pool
        t = y.shape[1]
        # Q^T b from C (square Y only: then every new direction b is in range(R)).
        self.cz = "wait" if y.shape[0] == t else "off"
        self.y_norm2 = float(np.linalg.norm(y, 2))
        self.cb = np.empty((qb.shape[0], t, BLOCK_CELLS), dtype=np.float32)
        self.scores = np.empty(qb.shape[0] * BLOCK_CELLS, dtype=np.float32)
        self.picked: list[int] = []  # their scores are set to -1 after each pass
        _in_threads(self._fill, qb.shape[0], threads, np.ascontiguousarray(self.r.T, dtype=np.float32), pool=pool)
        self.scale = float(self.scores[:n].max())

    def _fill(self, rt: np.ndarray, b0: int, b1: int) -> None:
        """C = Q^T R and the scores on blocks [b0, b1); rt is R^T (t, k) float32."""
        np.matmul(rt, self.qb[b0:b1], out=self.cb[b0:b1])
        kernels.block_scores(self.cb, self.scores, b0, b1)

    def atoms(self, j):
        """The float32 atoms (k,) of open row j, or (len(j), k) of an index array j."""
        return self.qb[j // BLOCK_CELLS, :, j % BLOCK_CELLS]

    def add(self, j: int, b: np.ndarray, update_scores: bool = True) -> None:
        """Account for the new orthonormal basis vector b (k,) of picked row j.

        update_scores=False (the last pick) updates R only: C and the scores are not needed.
        """
        u = b @ self.r  # (t,) = R^T b
        z = self._from_c(b) if update_scores else None
        self.r -= np.outer(b, u)
        self.picked.append(j)
        if update_scores:
            source, w = (self.qb, b) if z is None else (self.cb, z)
            _in_threads(kernels.rank1_step, self.qb.shape[0], self.threads, source, w.astype(np.float32),
                        self.cb, u.astype(np.float32), self.scores, pool=self.pool)
            self.scores[self.picked] = -1.0

    def _from_c(self, b: np.ndarray) -> np.ndarray | None:
        """z with R z = b (R before this pick), so that Q^T b = C z; None: use the Q pass.

        With Y square, R = (I - B B^T) Y has range = the complement of the basis B, which
        holds b: the pass then reads C only instead of Q and C. C's float32 error
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

    def best_column(self) -> int:
        """Row maximising ||R^T q_j||_1 among open rows (lowest on ties); -1 if all ~0."""
        scores = self.scores[:self.n]  # picked rows hold -1; the padding after n is ignored
        top = float(scores.max())
        if top <= 1e-5 * self.scale:  # nothing left above float32 noise
            return -1
        # float32 near-ties are settled in float64, lowest index first.
        close = np.flatnonzero(scores >= top - RESCORE_MARGIN * self.scale)
        return int(close[np.argmax(_scores64(self.atoms(close), self.r))])


def _scores64(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.abs(rows.astype(np.float64) @ r).sum(axis=1)
