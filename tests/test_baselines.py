"""Baselines: random, uniform stratified, and Nielsen et al. 2015 on small grids."""
from __future__ import annotations

import numpy as np
import pytest

from goniofrost.bench.baselines import (BaselineError, _descent, _GridMoves, condition_numbers,
                                  nielsen_path, nielsen_select, random_select, uniform_select)
from goniofrost.core.grid import MerlGrid

GRID = MerlGrid(12, 12, 24)
TINY = MerlGrid(4, 4, 8)


def smooth_z(grid: MerlGrid, k: int, seed: int = 0) -> np.ndarray:
    """A (n_valid, k) stand-in for scaled principal components: smooth functions of the cell
    angles with decreasing scale, like a PCA dictionary of BRDFs."""
    th, td, pd = grid.flat_angles(grid.valid_cells)
    rng = np.random.default_rng(seed)
    cols = [np.cos(a * th + b * td + c * pd + d) for a, b, c, d in rng.uniform(0, 4, (k, 4))]
    return np.stack(cols, axis=1) * np.linspace(10, 1, k)


def test_condition_numbers_known_values():
    stack = np.stack([np.diag([3.0, 1.0]), np.array([[1.0, 2.0], [2.0, 4.0]]), np.eye(2)])
    np.testing.assert_allclose(condition_numbers(stack), [3.0, np.inf, 1.0])


def test_random_select_distinct_valid_and_seeded():
    a = random_select(GRID, 30, np.random.default_rng(1))
    b = random_select(GRID, 30, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert len(set(a.tolist())) == 30 and a.min() >= 0 and a.max() < GRID.n_valid
    assert not np.array_equal(a, random_select(GRID, 30, np.random.default_rng(2)))
    with pytest.raises(BaselineError, match=f"only {GRID.n_valid} candidate cells"):
        random_select(GRID, GRID.n_valid + 1, np.random.default_rng(0))


@pytest.mark.parametrize("m", [1, 7, 20, 60])
def test_uniform_select_is_stratified(m):
    pos = uniform_select(GRID, m)
    assert pos.shape == (m,) and len(set(pos.tolist())) == m
    np.testing.assert_array_equal(pos, uniform_select(GRID, m))  # deterministic
    if m >= 20:  # spread over the index cube: both halves of every axis are sampled
        coords = np.stack(GRID.unravel(GRID.valid_cells[pos]), axis=1) / np.array(GRID.shape)
        assert np.all(coords.min(axis=0) < 0.5) and np.all(coords.max(axis=0) >= 0.5)


def test_uniform_select_refuses_bad_m():
    with pytest.raises(BaselineError, match="positive integer"):
        uniform_select(GRID, 0)


def test_nielsen_first_point_and_greedy_addition_by_brute_force():
    z = smooth_z(TINY, 3)
    steps = nielsen_path(z, [1, 2], TINY, np.random.default_rng(0), subset=10**6, max_iter=0)
    assert steps[0].positions.tolist() == [int(np.argmax(np.sum(z**2, axis=1)))]
    first = steps[0].positions[0]
    # With every free cell a candidate, the second point minimises cond over all of them.
    free = [p for p in range(TINY.n_valid) if p != first]
    conds = condition_numbers(np.stack([z[[first, p], :2] for p in free]))
    assert steps[1].positions[1] == free[int(np.argmin(conds))]
    assert steps[1].cond == pytest.approx(conds.min())


def test_nielsen_distinct_valid_deterministic_per_seed():
    z = smooth_z(GRID, 12)
    steps = nielsen_path(z, [4, 8, 12], GRID, np.random.default_rng(3), subset=50, max_iter=20)
    assert [s.m for s in steps] == [4, 8, 12]
    assert all(s.seconds >= 0 for s in steps) and steps[0].seconds <= steps[-1].seconds
    for s in steps:
        assert len(set(s.positions.tolist())) == s.m
        assert s.positions.min() >= 0 and s.positions.max() < GRID.n_valid
        assert s.cond == pytest.approx(condition_numbers(z[s.positions, :s.m][None])[0])
    again = nielsen_select(z, 12, GRID, np.random.default_rng(3), subset=50, max_iter=20)
    np.testing.assert_array_equal(again, steps[-1].positions)
    other = nielsen_select(z, 12, GRID, np.random.default_rng(4), subset=50, max_iter=20)
    assert not np.array_equal(other, again)


def test_descent_never_increases_the_condition_number():
    z = smooth_z(GRID, 10, seed=5)
    moves = _GridMoves(GRID)
    rng = np.random.default_rng(0)
    for trial in range(5):
        start = rng.choice(GRID.n_valid, size=10, replace=False)
        cond0 = condition_numbers(z[start, :10][None])[0]
        pos, cond, iters = _descent(z, start, cond0, moves, rng, max_iter=30)
        assert cond <= cond0
        assert cond == pytest.approx(condition_numbers(z[pos, :10][None])[0])
        assert len(set(pos.tolist())) == 10 and 1 <= iters <= 30


def test_grid_moves_stay_on_valid_cells_one_step_away():
    moves = _GridMoves(GRID)
    for p in (0, 100, GRID.n_valid - 1):
        neigh = moves.neighbours(p, 1)
        diff = np.abs(moves.coords[neigh] - moves.coords[p])
        assert np.all(diff.sum(axis=1) == 1)  # exactly one axis moved by one cell
        assert np.all(GRID.valid_mask[GRID.valid_cells[neigh]])


def test_nielsen_refuses_too_few_components_and_nan():
    z = smooth_z(GRID, 5)
    with pytest.raises(BaselineError, match="6 samples need at least 6 components, Z has 5"):
        nielsen_select(z, 6, GRID, 0)
    z[3, 2] = np.nan
    with pytest.raises(BaselineError, match="NaN or inf"):
        nielsen_select(z, 3, GRID, 0)
    with pytest.raises(BaselineError, match="a grid is needed"):
        nielsen_select(z, 3)
