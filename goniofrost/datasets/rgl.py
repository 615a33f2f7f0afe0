"""RGL tensor files (``.bsdf``) as a dataset (spec ``rgl:PATH``, a folder or one file).

Each file is evaluated at a cell's directions as Mitsuba 3's ``measured`` plugin does, divided by
cos theta_o; spectral files become linear sRGB. ``evaluate`` and ``tabulate`` give NaN where
theta_i lies outside the file's nodes; ``rendered`` gives the plugin's value everywhere. More:
docs/how-to/rgl-measurements.md.
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from goniofrost.brdf.rgl_measured import EVAL_VERSION, MeasuredFile, brdf, load_or_explain
from goniofrost.core.grid import FULL_GRID, half_diff_to_dirs
from goniofrost.datasets.base import Dataset, DatasetError, file_digest

# Files kept loaded (a full-size spectral file's RGB table is ~20 MB in float64).
RECENT_FILES = 4
# A cell on the last theta_i node up to float32 rounding of the node is inside the domain.
ELEVATION_TOLERANCE = 1e-6


class RglDataset(Dataset):
    """Materials stored as RGL tensor files: a folder of ``.bsdf`` files, or one file."""

    unmeasured_is_nan = True

    def __init__(self, path) -> None:
        self.path = Path(path)
        self.spec = f"rgl:{self.path}"
        self._files: dict[str, Path] | None = None
        self._recent: OrderedDict[str, MeasuredFile] = OrderedDict()
        self._digests: dict[tuple, str] = {}
        self._full_grid_w_i: np.ndarray | None = None

    def _paths(self) -> dict[str, Path]:
        if self._files is None:
            if self.path.is_file():
                files = [self.path]
            elif self.path.is_dir():
                files = sorted(self.path.glob("*.bsdf"))
                if not files:
                    raise DatasetError(f"{self.path}: no *.bsdf files found (rgl:PATH expects RGL tensor files)")
            else:
                raise DatasetError(f"{self.path}: no such file or folder (rgl:PATH expects a .bsdf file or a "
                                   f"folder of them)")
            self._files = {path.stem: path for path in files}
        return self._files

    def names(self) -> list[str]:
        return list(self._paths())

    def file(self, name: str) -> Path:
        """The .bsdf file of a material."""
        return self._paths()[self.resolve(name)]

    def content_id(self, name: str) -> str:
        return f"{EVAL_VERSION}:{file_digest(self._paths()[self.resolve(name)], self._digests)}"

    def load(self, name: str) -> MeasuredFile:
        """The checked file of a material (kept for the next few calls)."""
        name = self.resolve(name)
        if name not in self._recent:
            self._recent[name] = load_or_explain(self._paths()[name])
            while len(self._recent) > RECENT_FILES:
                self._recent.popitem(last=False)
        self._recent.move_to_end(name)
        return self._recent[name]

    def domain(self, name: str) -> str:
        """One line: the file's kind and the incident elevations it measured, with the share of
        the full grid's valid cells inside them."""
        if self._full_grid_w_i is None:  # shared by every file's domain
            self._full_grid_w_i = half_diff_to_dirs(*FULL_GRID.flat_angles(FULL_GRID.valid_cells))[0]
        inside = self._inside(name, self._full_grid_w_i)
        return (f"{self.load(name).domain_text()}; {int(inside.sum())} of {FULL_GRID.n_valid} valid cells of the "
                f"full grid measured")

    def measured_mask(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        """bool (...,): the cells whose incident elevation lies within the file's theta_i nodes."""
        w_i, _ = half_diff_to_dirs(theta_h, theta_d, phi_d)
        return self._inside(name, w_i)

    def _inside(self, name: str, w_i: np.ndarray) -> np.ndarray:
        nodes = self.load(name).theta_i
        theta_i = np.arccos(np.clip(w_i[..., 2], -1.0, 1.0))
        return (theta_i >= nodes[0] - ELEVATION_TOLERANCE) & (theta_i <= nodes[-1] + ELEVATION_TOLERANCE)

    def rendered(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        """The plugin's BRDF (..., 3) in 1/sr everywhere, the clamped slices beyond the domain included."""
        return self._values(name, *half_diff_to_dirs(theta_h, theta_d, phi_d))

    def _values(self, name: str, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
        values = brdf(self.load(name), w_i.reshape(-1, 3), w_o.reshape(-1, 3))
        return np.maximum(values, 0.0).reshape(*w_i.shape[:-1], 3)

    def evaluate(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        w_i, w_o = half_diff_to_dirs(theta_h, theta_d, phi_d)
        return np.where(self._inside(name, w_i)[..., None], self._values(name, w_i, w_o), np.nan)
