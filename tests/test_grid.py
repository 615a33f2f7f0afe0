"""MERL grid: cells <-> angles <-> directions, the valid mask (DESIGN.md, "Coordinates")."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from goniofrost.core.grid import FULL_GRID, MerlGrid, dirs_to_half_diff, half_diff_to_dirs

SMALL_GRID = MerlGrid(30, 30, 60)
GRIDS = {"full": FULL_GRID, "small": SMALL_GRID}
fractions = st.floats(0.0, 1.0, exclude_max=True)


def cells(grid: MerlGrid, min_td: int = 0):
    """Strategy: one cell (i_th, i_td, i_pd) of ``grid``."""
    return st.tuples(st.integers(0, grid.n_th - 1), st.integers(min_td, grid.n_td - 1),
                     st.integers(0, grid.n_pd - 1))


def test_full_grid_has_the_papers_number_of_valid_cells():
    assert FULL_GRID.size == 1_458_000
    assert FULL_GRID.n_valid == 1_111_432
    assert np.array_equal(FULL_GRID.valid_cells, np.flatnonzero(FULL_GRID.valid_mask))


@pytest.mark.parametrize("grid", GRIDS.values(), ids=GRIDS.keys())
def test_valid_mask_is_both_directions_above_the_surface(grid):
    # Written from the spherical geometry, independently of half_diff_to_dirs.
    th, td, pd = grid.flat_angles(np.arange(grid.size))
    cross = np.sin(th) * np.sin(td) * np.cos(pd)
    mu_i = np.cos(th) * np.cos(td) - cross
    mu_o = np.cos(th) * np.cos(td) + cross
    assert np.array_equal(grid.valid_mask, (mu_i > 0) & (mu_o > 0))
    assert np.array_equal(grid.valid_position(grid.valid_cells), np.arange(grid.n_valid))
    assert np.all(grid.valid_position(np.flatnonzero(~grid.valid_mask)) == -1)


@pytest.mark.parametrize("shape", [(90, 90, 180), (45, 45, 90), (30, 30, 60), (8, 8, 16), (7, 11, 13)])
def test_valid_mask_has_the_signs_of_every_cells_directions(shape):
    # The mask is computed from broadcast z components; the directions of every cell must give
    # the same signs, horizon cells (theta_h + theta_d = 90 deg) included.
    grid = MerlGrid(*shape)
    w_i, w_o = half_diff_to_dirs(*grid.flat_angles(np.arange(grid.size)))
    assert np.array_equal(grid.valid_mask, (w_i[:, 2] > 0) & (w_o[:, 2] > 0))


@pytest.mark.parametrize("shape", [(90, 90, 180), (45, 45, 90), (9, 11, 13)])
def test_the_cosine_weight_of_the_valid_cells_has_the_bits_of_their_directions(shape):
    """cosine_weight(grid) comes from the axes broadcast, cosine_weight(grid, cells) from every
    cell's directions: training's row weights must not move by a bit."""
    from goniofrost.core.grid import cosine_weight

    grid = MerlGrid(*shape)
    fast, each = cosine_weight(grid), cosine_weight(grid, grid.valid_cells)
    assert fast.shape == (grid.n_valid,) and fast.dtype == np.float64
    assert np.array_equal(fast.view(np.uint64), each.view(np.uint64))


def test_grids_of_one_shape_share_their_validity():
    a, b = MerlGrid(30, 30, 60), MerlGrid(30, 30, 60)
    assert a.valid_cells is b.valid_cells and a.valid_mask is b.valid_mask
    assert not a.valid_mask.flags.writeable and not a.valid_cells.flags.writeable


def test_lower_edge_formulas_match_the_design():
    th, td, pd = FULL_GRID.cell_angles(45, 30, 90)
    assert th == pytest.approx((45 / 90) ** 2 * np.pi / 2, rel=1e-15)
    assert td == pytest.approx(30 / 90 * np.pi / 2, rel=1e-15)
    assert pd == pytest.approx(np.pi / 2, rel=1e-15)
    assert FULL_GRID.flat_index(1, 2, 3) == (1 * 90 + 2) * 180 + 3


@pytest.mark.parametrize("name", GRIDS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_cell_flat_angles_round_trip_is_exact(name, data):
    grid = GRIDS[name]
    cell = data.draw(cells(grid))
    flat = grid.flat_index(*cell)
    assert tuple(int(i) for i in grid.unravel(flat)) == cell
    assert tuple(int(i) for i in grid.angle_cells(*grid.cell_angles(*cell))) == cell
    assert int(grid.angles_to_flat(*grid.flat_angles(flat))) == flat


@pytest.mark.parametrize("name", GRIDS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_angles_inside_a_cell_and_on_its_edge_up_to_rounding_map_to_it(name, data):
    grid = GRIDS[name]
    cell = data.draw(cells(grid))
    f = [data.draw(fractions) for _ in range(3)]
    th = ((cell[0] + f[0]) / grid.n_th) ** 2 * np.pi / 2
    td = (cell[1] + f[1]) / grid.n_td * np.pi / 2
    pd = (cell[2] + f[2]) / grid.n_pd * np.pi
    if max(f) < 1 - 1e-6:  # closer to the upper edge than the tolerance: the next cell
        assert tuple(int(i) for i in grid.angle_cells(th, td, pd)) == cell
    # the lower edges, a few ulps low (as a rounded computation may give them)
    edges = np.array(grid.cell_angles(*cell))
    for ulps in range(4):
        below = edges * (1 - ulps * np.finfo(float).eps)
        assert tuple(int(i) for i in grid.angle_cells(*below)) == cell


@settings(max_examples=100, deadline=None)
@given(cell=cells(SMALL_GRID), turns=st.integers(-3, 3))
def test_phi_d_is_folded_modulo_pi(cell, turns):
    th, td, pd = SMALL_GRID.cell_angles(*cell)
    mid = pd + 0.5 * np.pi / SMALL_GRID.n_pd
    assert tuple(int(i) for i in SMALL_GRID.angle_cells(th, td, mid + turns * np.pi)) == cell


@pytest.mark.parametrize("name", GRIDS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_directions_round_trip_to_the_same_cell(name, data):
    # i_td = 0 is excluded: at theta_d = 0 phi_d is degenerate (see the next test).
    grid = GRIDS[name]
    cell = data.draw(cells(grid, min_td=1))
    w_i, w_o = half_diff_to_dirs(*grid.cell_angles(*cell))
    np.testing.assert_allclose(np.linalg.norm([w_i, w_o], axis=-1), 1.0, rtol=1e-14)
    assert tuple(int(i) for i in grid.angle_cells(*dirs_to_half_diff(w_i, w_o))) == cell


@settings(max_examples=100, deadline=None)
@given(th=st.floats(0, np.pi / 2 - 1e-3), td=st.floats(0, np.pi / 2 - 1e-3), pd=st.floats(-np.pi, np.pi))
@example(th=1.56640625, td=5.96e-08, pd=0.0)  # grazing, theta_d ~ 0: td comes back 1.9e-9 off (arccos near 1)
def test_angles_to_directions_and_back_give_the_same_directions(th, td, pd):
    w_i, w_o = half_diff_to_dirs(th, td, pd)
    th2, td2, pd2 = dirs_to_half_diff(w_i, w_o)
    assert th2 == pytest.approx(th, abs=1e-7) and td2 == pytest.approx(td, abs=1e-7)
    # Compare the pairs up to a rotation about z (phi_h is not recovered, and at theta_h ~ 0 it
    # is degenerate): cos theta_i, cos theta_o and the angle between them fix a pair.
    v_i, v_o = half_diff_to_dirs(th2, td2, pd2)
    invariants = lambda a, b: np.array([a[2], b[2], a @ b])  # noqa: E731
    # to the angles' own tolerance: an angle 1e-7 off moves a cosine by up to 1e-7 (at grazing)
    np.testing.assert_allclose(invariants(v_i, v_o), invariants(w_i, w_o), atol=1e-7)


@settings(max_examples=100, deadline=None)
@given(th_i=st.floats(0, 1.5), th_o=st.floats(0, 1.5), phi=st.floats(0, 2 * np.pi), rot=st.floats(0, 2 * np.pi))
def test_direction_pairs_rotated_about_z_have_the_same_angles(th_i, th_o, phi, rot):
    def pair(r):
        w_i = np.array([np.sin(th_i) * np.cos(r), np.sin(th_i) * np.sin(r), np.cos(th_i)])
        w_o = np.array([np.sin(th_o) * np.cos(r + phi), np.sin(th_o) * np.sin(r + phi), np.cos(th_o)])
        return w_i, w_o
    if np.linalg.norm(np.add(*pair(0))) < 1e-3:
        return  # w_o = -w_i has no half vector
    a, b = dirs_to_half_diff(*pair(0.0)), dirs_to_half_diff(*pair(rot))
    # arccos near 1 resolves angles to sqrt(eps) ~ 1.5e-8 rad (1e-6 of a cell: harmless)
    np.testing.assert_allclose(a[:2], b[:2], atol=1e-7)
    # phi_d is degenerate where theta_d = 0 or theta_h = 0 (h = n: any phi_h)
    assert np.cos(a[2] - b[2]) == pytest.approx(1.0, abs=1e-9) or min(a[0], a[1]) < 1e-6
