"""The material tables of a benchmark: every material tabulated once per run and cached.

One float32 ``.npy`` (M, n_valid, 3) in the goniofrost cache, opened memory-mapped by the workers
so that they share the page cache.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from goniofrost.core.cache import cache_path, content_key
from goniofrost.datasets import open_dataset
from goniofrost.core.grid import MerlGrid
from goniofrost.bench.config import BenchError

# Materials tabulated per chunk: bounds the temporary memory whatever the grid.
MATERIALS_PER_CHUNK = 8


def material_names(specs) -> list[tuple[str, str]]:
    """(spec, name) of every material of the datasets, in dataset order."""
    return [(spec, name) for spec in specs for name in open_dataset(spec).names()]


def display_names(pairs: list[tuple[str, str]]) -> list[str]:
    """Material names for result rows; names held by two datasets are prefixed by their spec."""
    counts: dict[str, int] = {}
    for _, name in pairs:
        counts[name] = counts.get(name, 0) + 1
    return [name if counts[name] == 1 else f"{spec}:{name}" for spec, name in pairs]


def tables_path(specs, grid: MerlGrid, progress: bool = True) -> tuple[list[str], Path]:
    """Tabulate (or find cached) every material of ``specs`` on ``grid``.

    Returns the material names (see ``display_names``) and the path of a float32
    (M, grid.n_valid, 3) ``.npy`` in 1/sr, rows in ``grid.valid_cells`` order.
    """
    pairs = material_names(specs)
    datasets = {spec: open_dataset(spec) for spec in specs}
    ids = [datasets[spec].content_id(name) for spec, name in pairs]
    path = cache_path("bench-tables", content_key("bench-tables-v1", grid.as_dict(), ids), ".npy")
    if not path.is_file():
        _tabulate_into(path, pairs, datasets, grid, progress)
    return display_names(pairs), path


def _tabulate_into(path: Path, pairs, datasets, grid: MerlGrid, progress: bool) -> None:
    from goniofrost.core.progress import progress_bar

    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    out = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(len(pairs), grid.n_valid, 3))
    try:
        with progress_bar(total=len(pairs), asked=progress, desc="tabulating materials", unit="material",
                          leave=False) as bar:
            for start in range(0, len(pairs), MATERIALS_PER_CHUNK):
                chunk = pairs[start:start + MATERIALS_PER_CHUNK]
                for spec in dict.fromkeys(s for s, _ in chunk):
                    idx = [i for i, (s, _) in enumerate(chunk) if s == spec]
                    names = [chunk[i][1] for i in idx]
                    out[[start + i for i in idx]] = datasets[spec].tabulate(names, grid)
                bar.update(len(chunk))
        _require_finite(out, pairs, datasets)
        out.flush()
        del out
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _require_finite(tables: np.ndarray, pairs, datasets) -> None:
    """Refuse NaN or inf, but NaN of a dataset whose NaN means not measured (``rgl:PATH``)."""
    for i in range(tables.shape[0]):
        spec, name = pairs[i]
        if datasets[spec].unmeasured_is_nan:
            if np.isinf(tables[i]).any():
                raise BenchError(f"{spec}: material {name!r} tabulates to inf values")
        elif not np.all(np.isfinite(tables[i])):
            raise BenchError(f"{spec}: material {name!r} tabulates to NaN or inf values")


def open_tables(path) -> np.ndarray:
    """The cached tables, memory-mapped read-only: float32 (M, n_valid, 3)."""
    return np.load(path, mmap_mode="r")


