"""The MERL BRDF grid: cells <-> Rusinkiewicz angles <-> light/view directions.

* ``n_th x n_td x n_pd`` cells (MERL: 90 x 90 x 180); cell ``(i_th, i_td, i_pd)`` has flat index
  ``(i_th * n_td + i_td) * n_pd + i_pd``.
* A cell's angles are its lower edges: ``theta_h = (i_th / n_th)**2 * pi/2``,
  ``theta_d = i_td / n_td * pi/2``, ``phi_d = i_pd / n_pd * pi``.
* ``h = (sin th, 0, cos th)``, ``d = (sin td cos pd, sin td sin pd, cos td)``,
  ``w_i = R_y(theta_h) d``, ``w_o = 2 (w_i . h) h - w_i``; valid when both have z > 0.

Angles in radians; every function is vectorised over broadcastable arrays.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

HALF_PI = np.pi / 2
# An angle that lands within this fraction of a cell below an edge (floating-point
# rounding of the edge itself) is taken to sit on the edge, so cell -> angles -> cell is exact.
EDGE_TOLERANCE = 1e-7


@dataclass(frozen=True)
class MerlGrid:
    """A MERL-style (theta_h, theta_d, phi_d) grid; 90 x 90 x 180 by default.

    Smaller grids of the same construction (e.g. ``MerlGrid(30, 30, 60)``) serve fast tests.
    """

    n_th: int = 90
    n_td: int = 90
    n_pd: int = 180

    def __post_init__(self) -> None:
        for name in ("n_th", "n_td", "n_pd"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"MerlGrid.{name} must be a positive integer, got {value!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        """(n_th, n_td, n_pd)."""
        return (self.n_th, self.n_td, self.n_pd)

    @property
    def size(self) -> int:
        """Number of cells, valid or not."""
        return self.n_th * self.n_td * self.n_pd

    def as_dict(self) -> dict:
        """JSON-friendly description, e.g. ``{"n_th": 90, "n_td": 90, "n_pd": 180}``."""
        return {"n_th": self.n_th, "n_td": self.n_td, "n_pd": self.n_pd}

    # ----- index arithmetic -------------------------------------------------------------
    def flat_index(self, i_th, i_td, i_pd) -> np.ndarray:
        """Flat index (int64) of cells given their three integer indices."""
        i_th, i_td, i_pd = (np.asarray(a, dtype=np.int64) for a in (i_th, i_td, i_pd))
        return (i_th * self.n_td + i_td) * self.n_pd + i_pd

    def unravel(self, flat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Integer indices (i_th, i_td, i_pd) of flat cell indices."""
        flat = np.asarray(flat, dtype=np.int64)
        i_pd = flat % self.n_pd
        rest = flat // self.n_pd
        return rest // self.n_td, rest % self.n_td, i_pd

    # ----- cells <-> angles -------------------------------------------------------------
    def cell_angles(self, i_th, i_td, i_pd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lower-edge angles (theta_h, theta_d, phi_d) in radians of cells."""
        i_th, i_td, i_pd = (np.asarray(a, dtype=np.float64) for a in (i_th, i_td, i_pd))
        theta_h = (i_th / self.n_th) ** 2 * HALF_PI
        theta_d = i_td / self.n_td * HALF_PI
        phi_d = i_pd / self.n_pd * np.pi
        return theta_h, theta_d, phi_d

    def flat_angles(self, flat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lower-edge angles (theta_h, theta_d, phi_d) in radians of flat cell indices."""
        return self.cell_angles(*self.unravel(flat))

    def angle_cells(self, theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices (i_th, i_td, i_pd) containing angles in radians.

        ``phi_d`` is folded into [0, pi) first (phi_d and phi_d + pi are the same cell for an
        isotropic, reciprocal BRDF); indices are clamped into range.
        """
        x_th, x_td, x_pd = self.fractional_indices(theta_h, theta_d, phi_d)
        x_pd = np.where(x_pd >= self.n_pd - EDGE_TOLERANCE, 0.0, x_pd)  # fold 2*pi-ish back to 0
        return (
            _edge_floor(x_th, self.n_th),
            _edge_floor(x_td, self.n_td),
            _edge_floor(x_pd, self.n_pd),
        )

    def fractional_indices(self, theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_th, x_td, x_pd) float64: the grid's continuous indices of angles in radians (cell i
        spans [i, i + 1), its lower edge at i): x_th = sqrt(theta_h / 90 deg) n_th, x_td = theta_d /
        90 deg n_td, x_pd = (phi_d mod pi) / pi n_pd (phi_d and phi_d + pi are the same cell)."""
        theta_h, theta_d, phi_d = (np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d))
        return (np.sqrt(np.clip(theta_h, 0.0, None) / HALF_PI) * self.n_th, theta_d / HALF_PI * self.n_td,
                np.mod(phi_d, np.pi) / np.pi * self.n_pd)

    def angles_to_flat(self, theta_h, theta_d, phi_d) -> np.ndarray:
        """Flat index of the cells containing angles in radians."""
        return self.flat_index(*self.angle_cells(theta_h, theta_d, phi_d))

    # ----- validity -----------------------------------------------------------------------
    @property
    def valid_mask(self) -> np.ndarray:
        """Boolean (size,) array, read-only: True where both w_i and w_o of the cell have z > 0."""
        return _validity(self.shape)[0]

    @property
    def valid_cells(self) -> np.ndarray:
        """Flat indices (int64, ascending, read-only) of the valid cells; shape (n_valid,)."""
        return _validity(self.shape)[1]

    @property
    def n_valid(self) -> int:
        """Number of valid cells (1,111,432 on the full MERL grid)."""
        return int(self.valid_cells.size)

    def valid_position(self, flat) -> np.ndarray:
        """Position of flat cell indices within ``valid_cells``; -1 where a cell is invalid."""
        flat = np.asarray(flat, dtype=np.int64)
        lookup = np.full(self.size, -1, dtype=np.int64)
        lookup[self.valid_cells] = np.arange(self.n_valid)
        inside = (flat >= 0) & (flat < self.size)
        return np.where(inside, lookup[np.clip(flat, 0, self.size - 1)], -1)

    def cell_directions(self, flat) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions (w_i, w_o), each (..., 3), at the lower edges of flat cells."""
        return half_diff_to_dirs(*self.flat_angles(flat))


FULL_GRID = MerlGrid()


@lru_cache(maxsize=4)
def _validity(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(valid_mask, valid_cells) of the grid of ``shape``, computed once per process: every
    MerlGrid of that shape (a model's, a plan's, a dataset's) shares them (about 1 s at full size)."""
    grid = MerlGrid(*shape)
    mask = _valid_z(grid).reshape(-1)
    cells = np.flatnonzero(mask).astype(np.int64)
    mask.setflags(write=False)
    cells.setflags(write=False)
    return mask, cells


def _valid_z(grid: MerlGrid) -> np.ndarray:
    """bool (n_th, n_td, n_pd): w_i and w_o above the surface, from the z components alone.

    The same floating-point operations as ``half_diff_to_dirs`` on every cell (so the same signs
    where a cell's w_o lies on the horizon), on angles broadcast from their three axes: a tenth of
    the time of computing every direction."""
    z_i, z_o = _broadcast_z(grid)
    return (z_i > 0) & (z_o > 0)


def _broadcast_z(grid: MerlGrid) -> tuple[np.ndarray, np.ndarray]:
    """(w_i z, w_o z), float64 broadcast to (n_th, n_td, n_pd), with the floating-point operations
    of ``half_diff_to_dirs`` on angles broadcast from the grid's three axes."""
    th, td, pd = grid.cell_angles(np.arange(grid.n_th), np.arange(grid.n_td), np.arange(grid.n_pd))
    st, ct = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    d0 = (np.sin(td)[:, None] * np.cos(pd)[None, :])[None]
    d1 = (np.sin(td)[:, None] * np.sin(pd)[None, :])[None]
    d2 = np.cos(td)[None, :, None]
    x, z = ct * d0 + st * d2, -st * d0 + ct * d2        # w_i = R_y(theta_h) d: its x and z
    dot = x * st + d1 * 0.0 + z * ct                   # w_i . h, summed in np.sum's order
    return z, 2.0 * dot * ct - z                       # w_o = 2 (w_i . h) h - w_i


def _edge_floor(x: np.ndarray, n: int) -> np.ndarray:
    """floor(x), treating values within EDGE_TOLERANCE below an integer as that integer."""
    return np.clip(np.floor(x + EDGE_TOLERANCE), 0, n - 1).astype(np.int64)


def half_diff_to_dirs(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """Light and view directions (w_i, w_o), each (..., 3), of Rusinkiewicz angles (radians).

    Uses phi_h = 0; any rotation of both about z gives the same isotropic BRDF value.
    """
    theta_h, theta_d, phi_d = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d))
    )
    st, ct = np.sin(theta_h), np.cos(theta_h)
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    # w_i = R_y(theta_h) d
    w_i = np.stack([ct * d[..., 0] + st * d[..., 2], d[..., 1], -st * d[..., 0] + ct * d[..., 2]], -1)
    h = np.stack([st, np.zeros_like(st), ct], -1)
    w_o = 2.0 * np.sum(w_i * h, axis=-1, keepdims=True) * h - w_i
    return w_i, w_o


def dirs_to_half_diff(w_i, w_o) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz angles (theta_h, theta_d, phi_d) in radians of directions (..., 3).

    Inputs need not be normalised. phi_d is returned in (-pi, pi]; ``MerlGrid.angle_cells``
    folds it. Degenerate w_i = -w_o has no half vector and yields NaN.
    """
    w_i = _normalise(np.asarray(w_i, dtype=np.float64))
    w_o = _normalise(np.asarray(w_o, dtype=np.float64))
    h = _normalise(w_i + w_o)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    # d = R_y(-theta_h) R_z(-phi_h) w_i
    cp, sp = np.cos(phi_h), np.sin(phi_h)
    x = cp * w_i[..., 0] + sp * w_i[..., 1]
    y = -sp * w_i[..., 0] + cp * w_i[..., 1]
    z = w_i[..., 2]
    ct, st = np.cos(theta_h), np.sin(theta_h)
    dx, dz = ct * x - st * z, st * x + ct * z
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(y, dx)
    return theta_h, theta_d, phi_d


def _normalise(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def cosine_weight(grid: MerlGrid, cells=None) -> np.ndarray:
    """Row weight clip(cos theta_i * cos theta_o, 0.01, 1) of cells (default: valid cells).

    Returns float64 of the cells' shape. Used by training and reconstruction (DESIGN.md).
    """
    if cells is None:   # every valid cell: the z components alone, broadcast from the grid's axes
        return np.clip(_cosine_product(grid).reshape(-1)[grid.valid_cells], 0.01, 1.0)
    w_i, w_o = grid.cell_directions(np.asarray(cells, dtype=np.int64))
    return np.clip(w_i[..., 2] * w_o[..., 2], 0.01, 1.0)


def _cosine_product(grid: MerlGrid) -> np.ndarray:
    """cos theta_i * cos theta_o (n_th, n_td, n_pd) of every cell, float64, with the floating-point
    operations of ``half_diff_to_dirs`` (as ``_valid_z``) on angles broadcast from the three axes:
    the same values as from every cell's directions (a signed zero can differ, which the clip of
    ``cosine_weight`` removes) in a third of the time, without the (cells, 3) directions."""
    z_i, z_o = _broadcast_z(grid)
    return z_i * z_o
