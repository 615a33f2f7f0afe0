"""Baseline sample selections that FROST is benchmarked against.

``nielsen_select`` / ``nielsen_path`` (Nielsen, Jensen and Ramamoorthi 2015; random),
``random_select`` and ``uniform_select`` (stratified). Each returns ``positions``: int64 (m,)
distinct indices into ``grid.valid_cells``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid

# Nielsen's descent: the step starts at 3 cells and drops to 1 once an iteration improves the
# condition number by less than this fraction (0.001 percent); three such iterations end it.
NIELSEN_START_STEP = 3
NIELSEN_TOLERANCE = 1e-5
NIELSEN_STALL_LIMIT = 3
NIELSEN_MAX_ITER = 100


class BaselineError(GoniofrostError, ValueError):
    """A baseline selection that cannot be made (too many samples, too few candidates...)."""


def _check_m(m: int, available: int, what: str) -> int:
    if not isinstance(m, (int, np.integer)) or m < 1:
        raise BaselineError(f"{what}: the number of samples must be a positive integer, got {m!r}")
    if m > available:
        raise BaselineError(f"{what}: {m} samples requested but only {available} candidate cells exist")
    return int(m)


# ----- random and uniform -----------------------------------------------------------------
def random_select(grid: MerlGrid, m: int, rng: np.random.Generator) -> np.ndarray:
    """Draw m distinct valid cells uniformly; int64 (m,) positions into ``grid.valid_cells``."""
    m = _check_m(m, grid.n_valid, "random selection")
    return np.sort(rng.choice(grid.n_valid, size=m, replace=False)).astype(np.int64)


def uniform_select(grid: MerlGrid, m: int) -> np.ndarray:
    """Pick m valid cells stratified over the (i_th, i_td, i_pd) index space; deterministic.

    The index cube is cut into s x s x 2s boxes (the 90:90:180 aspect), with the smallest s that
    leaves at least m boxes holding valid cells; m of those boxes are taken evenly spaced in
    flat order, and from each the valid cell nearest to the box centre. Returns int64 (m,)
    positions into ``grid.valid_cells``.
    """
    m = _check_m(m, grid.n_valid, "uniform selection")
    coords = np.stack(grid.unravel(grid.valid_cells), axis=1).astype(np.float64)
    unit = (coords + 0.5) / np.array(grid.shape, dtype=np.float64)  # cell centres in [0, 1)^3
    for s in range(1, max(grid.shape) + 1):
        boxes_per_axis = np.array([s, s, 2 * s])
        box = np.minimum((unit * boxes_per_axis).astype(np.int64), boxes_per_axis - 1)
        box_id = (box[:, 0] * boxes_per_axis[1] + box[:, 1]) * boxes_per_axis[2] + box[:, 2]
        occupied = np.unique(box_id)
        if occupied.size >= m:
            break
    chosen = occupied[np.round(np.linspace(0, occupied.size - 1, m)).astype(np.int64)]
    centre_dist = np.sum((unit * boxes_per_axis - (box + 0.5)) ** 2, axis=1)
    order = np.lexsort((centre_dist, box_id))  # by box, then nearest to the box centre first
    first_in_box = order[np.searchsorted(box_id[order], chosen)]
    positions = np.unique(first_in_box)
    if positions.size < m:  # cannot happen with distinct boxes; guard the contract anyway
        raise BaselineError(f"uniform selection: found {positions.size} cells for m={m}")
    return positions.astype(np.int64)


# ----- Nielsen et al. 2015 -----------------------------------------------------------------
def condition_numbers(matrices: np.ndarray) -> np.ndarray:
    """2-norm condition numbers of a stack of square matrices (..., k, k).

    inf when a matrix is singular to working precision (sigma_min <= k eps sigma_max, the
    LAPACK rank rule), so a rounding-level sigma_min never passes for a finite condition.
    """
    s = np.linalg.svd(np.asarray(matrices, dtype=np.float64), compute_uv=False)
    k = s.shape[-1]
    singular = s[..., -1] <= s[..., 0] * k * np.finfo(np.float64).eps
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = s[..., 0] / s[..., -1]
    return np.where(singular | ~np.isfinite(cond), np.inf, cond)


@dataclass
class NielsenStep:
    """The state of one Nielsen run after ``m`` points: positions (m,), condition number, seconds
    since the start of the run (greedy additions and descents for 1..m points)."""

    m: int
    positions: np.ndarray
    cond: float
    seconds: float
    descent_iterations: list = field(default_factory=list)


class _GridMoves:
    """Neighbour moves on the grid between valid cells, by position into ``grid.valid_cells``."""

    def __init__(self, grid: MerlGrid) -> None:
        self.grid = grid
        self.coords = np.stack(grid.unravel(grid.valid_cells), axis=1)  # (n_valid, 3) int64
        lookup = np.full(grid.size, -1, dtype=np.int64)
        lookup[grid.valid_cells] = np.arange(grid.n_valid)
        self.lookup = lookup
        self.shape = np.array(grid.shape)

    def neighbours(self, position: int, step: int) -> np.ndarray:
        """Valid positions one +-step move away along each grid axis (up to 6)."""
        offsets = np.concatenate([np.eye(3, dtype=np.int64), -np.eye(3, dtype=np.int64)]) * step
        target = self.coords[position] + offsets
        inside = np.all((target >= 0) & (target < self.shape), axis=1)
        target = target[inside]
        flat = (target[:, 0] * self.shape[1] + target[:, 1]) * self.shape[2] + target[:, 2]
        moved = self.lookup[flat]
        return moved[moved >= 0]


def _z_matrix(z: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """The square matrix of the selected rows and the first len(positions) columns of Z."""
    k = positions.shape[-1]
    return z[positions, :k]


def _greedy_add(z, positions, rng, subset: int) -> tuple[np.ndarray, float]:
    """Add the best of a random candidate subset by condition number (one greedy step)."""
    n = z.shape[0]
    taken = np.zeros(n, dtype=bool)
    taken[positions] = True
    free = np.flatnonzero(~taken)
    cand = free if free.size <= subset else rng.choice(free, size=subset, replace=False)
    k = positions.size + 1
    base = np.broadcast_to(z[positions, :k], (cand.size, k - 1, k))
    stack = np.concatenate([base, z[cand, None, :k]], axis=1)
    cond = condition_numbers(stack)
    best = int(np.argmin(cond))
    return np.append(positions, cand[best]), float(cond[best])


def _descent(z, positions, cond, moves: _GridMoves, rng, max_iter: int) -> tuple[np.ndarray, float, int]:
    """Discrete descent: move points by +-step on each grid axis while the condition drops."""
    step, stalls, positions = NIELSEN_START_STEP, 0, positions.copy()
    k = positions.size
    for iteration in range(1, max_iter + 1):
        before = cond
        for p in rng.permutation(k):
            cand = moves.neighbours(positions[p], step)
            cand = cand[~np.isin(cand, positions)]  # points stay distinct
            if cand.size == 0:
                continue
            stack = np.repeat(z[positions, :k][None], cand.size, axis=0)
            stack[:, p, :] = z[cand, :k]
            cand_cond = condition_numbers(stack)
            best = int(np.argmin(cand_cond))
            if cand_cond[best] < cond:
                positions[p], cond = cand[best], float(cand_cond[best])
        # A NaN difference (inf before and after) counts as no improvement too.
        if not before - cond >= NIELSEN_TOLERANCE * before:
            stalls, step = stalls + 1, 1
            if stalls >= NIELSEN_STALL_LIMIT:
                return positions, cond, iteration
    return positions, cond, max_iter


def nielsen_path(
    z: np.ndarray,
    m_values,
    grid: MerlGrid,
    rng: np.random.Generator,
    subset: int = 500,
    max_iter: int = NIELSEN_MAX_ITER,
) -> list[NielsenStep]:
    """Run Nielsen's selection up to max(m_values) points; return the state at each m.

    ``z``: (n_valid, K) scaled principal components (a model's ``dictionary``), K >= max m.
    The run is incremental: the design for m points is the state after the m-th greedy addition
    and its descent, and its ``seconds`` is the wall time from the start of the run, so the
    designs for all m come from one run exactly as running to each m separately would give.
    """
    wanted = sorted({int(m) for m in m_values})
    m_max = _check_m(wanted[-1], grid.n_valid, "Nielsen selection")
    _check_nielsen_inputs(z, grid, m_max, subset, max_iter)
    moves = _GridMoves(grid)
    start = time.perf_counter()
    # The first point is the row of Z with the largest norm.
    positions = np.array([int(np.argmax(np.einsum("ij,ij->i", z, z)))], dtype=np.int64)
    cond, steps, iters = 1.0, [], []
    for m in range(1, m_max + 1):
        if m > 1:
            positions, cond = _greedy_add(z, positions, rng, subset)
        positions, cond, used = _descent(z, positions, cond, moves, rng, max_iter)
        iters.append(used)
        if m in wanted:
            steps.append(NielsenStep(m, positions.copy(), cond, time.perf_counter() - start, list(iters)))
    return steps


def _check_nielsen_inputs(z, grid: MerlGrid, m_max: int, subset: int, max_iter: int) -> None:
    if z.ndim != 2 or z.shape[0] != grid.n_valid:
        raise BaselineError(
            f"Nielsen selection: Z must be (n_valid={grid.n_valid}, K), got shape {z.shape}")
    if z.shape[1] < m_max:
        raise BaselineError(
            f"Nielsen selection: {m_max} samples need at least {m_max} components, Z has {z.shape[1]}")
    if not np.all(np.isfinite(z)):
        raise BaselineError("Nielsen selection: Z holds NaN or inf")
    if subset < 1 or max_iter < 0:
        raise BaselineError(f"Nielsen selection: subset must be >= 1 and max_iter >= 0, got {subset}, {max_iter}")


def nielsen_select(model_or_z, m: int, grid: MerlGrid | None = None, rng=None,
                   subset: int = 500, max_iter: int = NIELSEN_MAX_ITER) -> np.ndarray:
    """Nielsen et al. 2015 selection of m cells; int64 (m,) positions into ``grid.valid_cells``.

    ``model_or_z``: a FrostModel (its ``dictionary`` and ``grid`` are used) or a (n_valid, K)
    array Z with ``grid`` given. ``rng``: a numpy Generator or a seed (default 0).
    """
    z = getattr(model_or_z, "dictionary", model_or_z)
    grid = grid if grid is not None else getattr(model_or_z, "grid", None)
    if grid is None:
        raise BaselineError("Nielsen selection: a grid is needed when Z is given as an array")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
    return nielsen_path(np.asarray(z), [m], grid, rng, subset, max_iter)[-1].positions
