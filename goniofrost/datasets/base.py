"""The one interface every material dataset follows, and the errors it raises."""
from __future__ import annotations

import difflib
import hashlib
from abc import ABC, abstractmethod
from typing import Sequence

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import FULL_GRID, MerlGrid

# Cells evaluated per chunk: bounds memory to a few hundred MB whatever the grid.
CHUNK_CELLS = 1 << 17


class DatasetError(GoniofrostError, ValueError):
    """A dataset spec or file cannot be used (names the spec or file and what was expected)."""


class UnknownMaterialError(GoniofrostError, KeyError):
    """A material name that the dataset does not hold; the message suggests close names."""

    def __str__(self) -> str:  # KeyError quotes its message; show it plainly
        return str(self.args[0])


class Dataset(ABC):
    """A named collection of isotropic BRDFs that can be evaluated at any angles.

    Subclasses give ``spec``, ``names()``, ``evaluate()`` and ``content_id()``; ``tabulate``
    evaluates materials over grid cells in chunks.
    """

    spec: str
    # True when ``evaluate`` and ``tabulate`` give NaN at cells the material has no data for (not
    # measured: ``rgl:PATH``); training, benchmarks and the error metric then leave those cells out.
    unmeasured_is_nan = False

    @abstractmethod
    def names(self) -> list[str]:
        """Material names, in the dataset's own order."""

    @abstractmethod
    def evaluate(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        """BRDF (R, G, B) in 1/sr, >= 0, at Rusinkiewicz angles in radians; shape (..., 3)."""

    @abstractmethod
    def content_id(self, name: str) -> str:
        """A string that changes whenever the material's values could change (for caching)."""

    def rendered(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        """BRDF (..., 3) a renderer shows everywhere (the simulated camera's): ``evaluate`` unless
        the dataset has cells without data, where it gives its renderer's value."""
        return self.evaluate(name, theta_h, theta_d, phi_d)

    def domain(self, name: str) -> str:
        """One line saying which cells the material has data for."""
        return "every valid cell"

    def resolve(self, name: str) -> str:
        """Return ``name`` if the dataset holds it; else raise UnknownMaterialError."""
        names = self.names()
        if name in names:
            return name
        close = difflib.get_close_matches(name, names, n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise UnknownMaterialError(f"unknown material {name!r} in dataset {self.spec!r}{hint}")

    def tabulate(
        self,
        names: Sequence[str] | None = None,
        grid: MerlGrid = FULL_GRID,
        cells: np.ndarray | None = None,
    ) -> np.ndarray:
        """Evaluate materials on grid cells (default: every valid cell).

        Returns float32 (len(names), n_cells, 3) in 1/sr, negative values clamped to 0.
        """
        names = self.names() if names is None else [self.resolve(n) for n in names]
        cells = grid.valid_cells if cells is None else np.asarray(cells, dtype=np.int64)
        out = np.empty((len(names), cells.size, 3), dtype=np.float32)
        for start in range(0, cells.size, CHUNK_CELLS):
            chunk = cells[start:start + CHUNK_CELLS]
            out[:, start:start + chunk.size] = self._evaluate_many(names, *grid.flat_angles(chunk))
        return out

    def _evaluate_many(self, names: Sequence[str], theta_h, theta_d, phi_d) -> np.ndarray:
        """(len(names), N, 3) values at N angle triples; subclasses may batch this."""
        return np.stack([self.evaluate(n, theta_h, theta_d, phi_d) for n in names])


def file_digest(path, digests: dict) -> str:
    """The blake2b-128 hex digest of the file at ``path``, read in 4 MB blocks; ``digests`` keeps it
    by (path, size, mtime), so an unchanged file is read once (a dataset's content ids)."""
    stat = path.stat()
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key not in digests:
        digest = hashlib.blake2b(digest_size=16)
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 22), b""):
                digest.update(block)
        digests[key] = digest.hexdigest()
    return digests[key]
