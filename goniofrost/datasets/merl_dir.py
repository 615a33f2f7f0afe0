"""A folder of MERL .binary files as a dataset (spec ``merl:DIR``).

A material's name is its file name without ``.binary``; a value is its cell's (piecewise constant).
Missing values read as 0 below the horizon and are an error at a valid cell (a training material
must cover every valid cell).
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Sequence

import numpy as np

from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.brdf.merl_file import read_merl
from goniofrost.datasets.base import Dataset, DatasetError, file_digest

# Materials kept in memory (35 MB each at full resolution).
RECENT_FILES = 4


class MerlDirDataset(Dataset):
    """Materials stored as MERL .binary files in one folder."""

    def __init__(self, folder) -> None:
        self.folder = Path(folder)
        self.spec = f"merl:{self.folder}"
        self._files: dict[str, Path] | None = None
        self._recent: OrderedDict[str, tuple[MerlGrid, np.ndarray]] = OrderedDict()
        self._digests: dict[tuple, str] = {}

    def _paths(self) -> dict[str, Path]:
        if self._files is None:
            if not self.folder.is_dir():
                raise DatasetError(f"{self.folder}: no such folder (merl:DIR expects a folder of MERL .binary files)")
            files = sorted(self.folder.glob("*.binary"))
            if not files:
                raise DatasetError(f"{self.folder}: no *.binary files found (merl:DIR expects MERL .binary files)")
            self._files = {path.stem: path for path in files}
        return self._files

    def names(self) -> list[str]:
        return list(self._paths())

    def content_id(self, name: str) -> str:
        return f"merl-v1:{file_digest(self._paths()[self.resolve(name)], self._digests)}"

    def load(self, name: str) -> tuple[MerlGrid, np.ndarray]:
        """(grid of the file, float64 (grid.size, 3) BRDF in 1/sr with NaN = missing)."""
        name = self.resolve(name)
        if name not in self._recent:
            path = self._paths()[name]
            brdf = read_merl(path)  # validates header and size first
            file_grid = MerlGrid(*np.fromfile(path, dtype="<i4", count=3).tolist())
            self._recent[name] = (file_grid, brdf)
            while len(self._recent) > RECENT_FILES:
                self._recent.popitem(last=False)
        self._recent.move_to_end(name)
        return self._recent[name]

    def evaluate(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        grid, brdf = self.load(name)
        flat = grid.angles_to_flat(theta_h, theta_d, phi_d)
        return self._values(name, grid, brdf, flat)

    def tabulate(self, names: Sequence[str] | None = None, grid: MerlGrid = FULL_GRID,
                 cells: np.ndarray | None = None) -> np.ndarray:
        """float32 (len(names), n_cells, 3): one file at a time (each is read once)."""
        names = self.names() if names is None else [self.resolve(n) for n in names]
        cells = grid.valid_cells if cells is None else np.asarray(cells, dtype=np.int64)
        angles = None
        out = np.empty((len(names), cells.size, 3), dtype=np.float32)
        for i, name in enumerate(names):
            file_grid, brdf = self.load(name)
            if file_grid == grid:  # same grid: the cells are the file's own
                out[i] = self._values(name, file_grid, brdf, cells)
                continue
            angles = grid.flat_angles(cells) if angles is None else angles
            out[i] = self._values(name, file_grid, brdf, file_grid.angles_to_flat(*angles))
        return out

    def _values(self, name: str, grid: MerlGrid, brdf: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """Values (flat.shape + (3,)) of the file's cells; see the module docstring for NaN."""
        values = brdf[flat]
        missing = np.isnan(values).any(axis=-1)
        bad = missing & grid.valid_mask[flat]
        if bad.any():
            first = tuple(int(v) for v in grid.unravel(np.asarray(flat)[bad].flat[0]))
            raise DatasetError(
                f"{self._paths()[name]}: valid cells without a value (negative in the file): "
                f"{int(bad.sum())}, first at (i_th, i_td, i_pd) = {first}; material {name!r} must cover every "
                "valid cell to be tabulated or evaluated")
        return np.where(missing[..., None], 0.0, values)
