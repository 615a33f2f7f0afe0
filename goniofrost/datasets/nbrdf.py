"""Neural-BRDF networks (Sztrajman et al. 2021) stored as one .npz per database.

Arrays (float32): ``names`` (M,), ``W1`` (M,6,21), ``b1`` (M,21), ``W2`` (M,21,21), ``b2`` (M,21),
``W3`` (M,21,3), ``b3`` (M,3). With ``x = (sin th, 0, cos th, sin td cos pd, sin td sin pd, cos td)``
the BRDF is ``exp(relu(relu(x W1 + b1) W2 + b2) W3 + b3) - 1``, clamped to >= 0, in 1/sr.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Sequence

import numpy as np

from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.datasets.base import Dataset, DatasetError
from goniofrost.datasets.parallel import tabulate_blocks

LAYER_KEYS = ("W1", "b1", "W2", "b2", "W3", "b3")
# Cells per block when tabulating: the hidden layers of a batch of materials stay in cache.
BLOCK_CELLS = 16384


class NbrdfDataset(Dataset):
    """Materials held as small networks in one .npz archive; evaluated in float32."""

    def __init__(self, path) -> None:
        self.path = Path(path)
        self.spec = f"nbrdf:{self.path}"
        self._weights: dict[str, np.ndarray] | None = None
        self._index: dict[str, int] = {}
        self._digest = ""

    def _load(self) -> dict[str, np.ndarray]:
        if self._weights is None:
            self._weights = _read_archive(self.path)
            self._index = {n: i for i, n in enumerate(self._weights["names"])}
            self._digest = hashlib.sha256(self.path.read_bytes()).hexdigest()[:16]
        return self._weights

    def names(self) -> list[str]:
        return [str(n) for n in self._load()["names"]]

    def content_id(self, name: str) -> str:
        self._load()
        return f"nbrdf-v1:{self._digest}:{self.resolve(name)}"

    def evaluate(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        return self._evaluate_many([name], theta_h, theta_d, phi_d)[0]

    def tabulate(self, names: Sequence[str] | None = None, grid: MerlGrid = FULL_GRID,
                 cells: np.ndarray | None = None) -> np.ndarray:
        """float32 (len(names), n_cells, 3): blocks of cells on one thread per core, BLAS
        single-threaded (see ``parallel``)."""
        self._load()  # before the threads: loading is not thread-safe
        names = self.names() if names is None else [self.resolve(n) for n in names]
        cells = grid.valid_cells if cells is None else np.asarray(cells, dtype=np.int64)
        return tabulate_blocks(self._evaluate_many, names, grid, cells, BLOCK_CELLS)

    def _evaluate_many(self, names: Sequence[str], theta_h, theta_d, phi_d) -> np.ndarray:
        """(len(names), *shape, 3) in float32.

        Computed transposed (features x points), so every product is a BLAS sgemm with a long
        output row; the first layer of all materials is one product; updates are in place.
        Several times faster than (points x features) batched products.
        """
        weights = self._load()
        idx = np.array([self._index[self.resolve(n)] for n in names])
        x = network_input(theta_h, theta_d, phi_d)
        shape = x.shape[:-1]
        x_t = np.ascontiguousarray(x.reshape(-1, 6).T)  # (6, N)
        m = idx.size
        w1 = weights["W1"][idx].transpose(0, 2, 1).reshape(m * 21, 6)
        h = (w1 @ x_t).reshape(m, 21, -1)  # (m, 21, N)
        h += weights["b1"][idx][:, :, None]
        np.maximum(h, 0.0, out=h)
        h = np.matmul(weights["W2"][idx].transpose(0, 2, 1), h)
        h += weights["b2"][idx][:, :, None]
        np.maximum(h, 0.0, out=h)
        y = np.matmul(weights["W3"][idx].transpose(0, 2, 1), h)  # (m, 3, N)
        y += weights["b3"][idx][:, :, None]
        np.expm1(y, out=y)
        np.maximum(y, 0.0, out=y)
        return y.transpose(0, 2, 1).reshape(m, *shape, 3)


def network_input(theta_h, theta_d, phi_d) -> np.ndarray:
    """Float32 (..., 6) network input of Rusinkiewicz angles in radians (phi_h = 0)."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d))
    )
    std = np.sin(theta_d)
    x = np.stack([np.sin(theta_h), np.zeros_like(theta_h), np.cos(theta_h),
                  std * np.cos(phi_d), std * np.sin(phi_d), np.cos(theta_d)], axis=-1)
    return x.astype(np.float32)


def _read_archive(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise DatasetError(f"{path}: no such Neural-BRDF archive (expected an .npz file)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = {k: archive[k] for k in archive.files}
    except ValueError:
        # not a zip: numpy tries it as a pickle and refuses, advising to "load it unsafely"
        raise DatasetError(f"{path}: not a readable .npz archive (not in NumPy's .npz format)") from None
    except OSError as exc:
        raise DatasetError(f"{path}: not a readable .npz archive ({exc})") from exc
    missing = [k for k in ("names", *LAYER_KEYS) if k not in data]
    if missing:
        raise DatasetError(f"{path}: missing arrays {missing}; expected names, W1, b1, W2, b2, W3, b3")
    m = data["names"].shape[0]
    expected = {"W1": (m, 6, 21), "b1": (m, 21), "W2": (m, 21, 21), "b2": (m, 21), "W3": (m, 21, 3), "b3": (m, 3)}
    for key, shape in expected.items():
        if data[key].shape != shape:
            raise DatasetError(f"{path}: array {key} has shape {data[key].shape}, expected {shape}")
        data[key] = data[key].astype(np.float32)
    return data
