"""Tabulated materials with an on-disk cache, and several datasets combined into one list.

One float32 ``.npy`` (n_valid, 3) per material and grid under ``<cache dir>/tabulated/``, named by
a hash of the dataset's ``content_id(name)`` and the grid. ``collect_materials`` labels a material
``SPEC:NAME`` when two datasets hold its name.
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from goniofrost.core.cache import atomic_replace, cache_path, content_key
from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.datasets.specs import open_dataset
from goniofrost.datasets.base import Dataset, DatasetError, UnknownMaterialError

# Bump when the tabulation itself changes (cells, dtype, clamping): invalidates every entry.
TABULATE_VERSION = "tabulate-v1"
# Materials evaluated per call: batched evaluation without a huge temporary.
MATERIALS_PER_BATCH = 8


def cache_entry(dataset: Dataset, name: str, grid: MerlGrid = FULL_GRID) -> Path:
    """Cache path of a material's values on the valid cells of ``grid``."""
    key = content_key(TABULATE_VERSION, dataset.content_id(name), grid.as_dict())
    return cache_path("tabulated", key, ".npy")


def tabulate_cached(dataset: Dataset, names: Sequence[str] | None = None,
                    grid: MerlGrid = FULL_GRID, progress: bool | None = None) -> np.ndarray:
    """BRDFs of materials on the valid cells of ``grid``, computed once and then read from disk.

    Returns float32 (len(names), grid.n_valid, 3) in 1/sr (default: every material).
    ``progress``: tqdm bar on stderr; None shows it when more than one material is computed.
    """
    names = dataset.names() if names is None else [dataset.resolve(n) for n in names]
    out = np.empty((len(names), grid.n_valid, 3), dtype=np.float32)
    for i, values in enumerate(_cached_values(dataset, names, grid, progress)):
        out[i] = values
    return out


def tabulated_files(dataset: Dataset, names: Sequence[str], grid: MerlGrid = FULL_GRID,
                    progress: bool | None = None) -> list[Path]:
    """The cache entries (``.npy``, float32 (n_valid, 3)) of these materials, computed when
    missing; nothing is kept in memory (training reads them in row chunks)."""
    names = [dataset.resolve(n) for n in names]
    for _ in _cached_values(dataset, names, grid, progress):
        pass
    return [cache_entry(dataset, name, grid) for name in names]


def _cached_values(dataset: Dataset, names: list[str], grid: MerlGrid, progress: bool | None):
    """Yield every material's (n_valid, 3) values in order (memory-mapped when cached, else
    computed in batches and saved first)."""
    paths = [cache_entry(dataset, name, grid) for name in names]
    cached = [_load(path, grid) for path in paths]
    todo = [i for i, values in enumerate(cached) if values is None]
    computed = {}
    with _bar(len(todo), progress) as bar:
        for start in range(0, len(todo), MATERIALS_PER_BATCH):
            batch = todo[start:start + MATERIALS_PER_BATCH]
            values = dataset.tabulate([names[i] for i in batch], grid)
            _require_finite(dataset, [names[i] for i in batch], values)
            for j, i in enumerate(batch):
                _save(paths[i], values[j])
                computed[i] = _load(paths[i], grid)
            bar.update(len(batch))
    for i, values in enumerate(cached):
        yield values if values is not None else computed.pop(i)


def _load(path: Path, grid: MerlGrid) -> np.ndarray | None:
    """A cached entry (memory-mapped), or None when absent or not of the expected shape."""
    if not path.is_file():
        return None
    try:
        values = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError):
        return None  # unreadable entry: recompute and overwrite it
    if values.shape != (grid.n_valid, 3) or values.dtype != np.float32:
        return None
    return values


def _save(path: Path, values: np.ndarray) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as handle:
            np.save(handle, np.ascontiguousarray(values, dtype=np.float32))
        atomic_replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _require_finite(dataset: Dataset, names: Sequence[str], values: np.ndarray) -> None:
    """Refuse NaN or inf, but NaN of a dataset whose NaN means not measured (``unmeasured_is_nan``)."""
    for name, table in zip(names, values):
        bad = np.isinf(table) if dataset.unmeasured_is_nan else ~np.isfinite(table)
        if bad.any():
            raise DatasetError(f"{dataset.spec}: material {name!r} gives {int(bad.any(-1).sum())} "
                               "non-finite values on the grid")


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def update(self, n: int) -> None:
        return None


def _bar(total: int, progress: bool | None):
    if not (progress or (progress is None and total > 1)) or total == 0:
        return _NoBar()
    from goniofrost.core.progress import progress_bar
    return progress_bar(total=total, desc="tabulating", unit="material", leave=False)


# ----- several datasets ------------------------------------------------------------------------
@dataclass(frozen=True)
class Material:
    """One material of a combined list: its dataset, its own name and a label unique in the list."""

    dataset: Dataset
    name: str
    label: str


def open_datasets(specs: Sequence[str]) -> list[Dataset]:
    """Open each dataset spec once (repeats are ignored), in order."""
    if not specs:
        raise DatasetError("no dataset given: expected at least one of builtin, nbrdf:PATH.npz, merl:DIR, rgl:PATH")
    return [open_dataset(spec) for spec in dict.fromkeys(specs)]


def collect_materials(specs: Sequence[str], only: Sequence[str] | None = None,
                      exclude: Sequence[str] | None = None) -> list[Material]:
    """Every material of the datasets, in order, filtered by ``only`` and ``exclude``.

    A selector matches a material's label, its ``SPEC:NAME`` or its plain name (then every
    dataset's material of that name). A selector that matches nothing is an error with close
    names suggested (a typo must not silently change a training set); so is an empty result.
    """
    datasets = open_datasets(specs)
    pairs = [(ds, name) for ds in datasets for name in ds.names()]
    counts: dict[str, int] = {}
    for _, name in pairs:
        counts[name] = counts.get(name, 0) + 1
    materials = [Material(ds, name, name if counts[name] == 1 else f"{ds.spec}:{name}")
                 for ds, name in pairs]
    if only:
        materials = [m for m in materials if _matches(m, _check_selectors(materials, only, "--only"))]
    if exclude:
        drop = _check_selectors(materials, exclude, "--exclude")
        materials = [m for m in materials if not _matches(m, drop)]
    if not materials:
        raise DatasetError(f"no materials left of datasets {list(specs)} after --only/--exclude")
    return materials


def _keys(material: Material) -> set[str]:
    return {material.label, material.name, f"{material.dataset.spec}:{material.name}"}


def _matches(material: Material, selectors: set[str]) -> bool:
    return not _keys(material).isdisjoint(selectors)


def _check_selectors(materials: list[Material], selectors: Sequence[str], option: str) -> set[str]:
    known = set().union(*(_keys(m) for m in materials)) if materials else set()
    for selector in selectors:
        if selector not in known:
            close = difflib.get_close_matches(selector, sorted(known), n=3, cutoff=0.5)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise UnknownMaterialError(f"{option} {selector!r}: no such material in the datasets{hint}")
    return set(selectors)


def tabulated_material_files(materials: Sequence[Material], grid: MerlGrid = FULL_GRID,
                             progress: bool | None = None) -> list[Path]:
    """The tabulation cache entries of ``materials``, in order, computed when missing."""
    files: list[Path | None] = [None] * len(materials)
    groups: dict[int, list[int]] = {}
    for i, material in enumerate(materials):
        groups.setdefault(id(material.dataset), []).append(i)
    for indices in groups.values():
        dataset = materials[indices[0]].dataset
        for i, path in zip(indices, tabulated_files(dataset, [materials[i].name for i in indices], grid, progress)):
            files[i] = path
    return files


def tabulate_materials(materials: Sequence[Material], grid: MerlGrid = FULL_GRID,
                       progress: bool | None = None) -> np.ndarray:
    """float32 (len(materials), grid.n_valid, 3) in 1/sr, in order, through the cache."""
    out = np.empty((len(materials), grid.n_valid, 3), dtype=np.float32)
    groups: dict[int, list[int]] = {}
    for i, material in enumerate(materials):
        groups.setdefault(id(material.dataset), []).append(i)
    for indices in groups.values():
        dataset = materials[indices[0]].dataset
        out[indices] = tabulate_cached(dataset, [materials[i].name for i in indices], grid, progress)
    return out


class TabulatedFiles:
    """M tabulated materials read from their cache files in row chunks, never all in memory.

    Stands in for the stacked float32 (M, n_valid, 3) array of ``tabulate_materials`` where only
    row chunks are needed (training: 151 materials at full size are 2 GB). Plain reads, not a
    memory map, so what was read leaves the process's memory with the chunk.
    """

    ndim = 3

    def __init__(self, paths: Sequence[Path]) -> None:
        self.paths = [Path(p) for p in paths]
        self.offsets = [_npy_data_offset(p) for p in self.paths]
        rows = {shape[0] for _, shape in self.offsets}
        if len(rows) > 1:
            raise DatasetError(f"tabulated files of different grids: {sorted(rows)} rows")
        self.shape = (len(self.paths), rows.pop() if rows else 0, 3)

    def rows(self, start: int, stop: int) -> np.ndarray:
        """float32 (stop - start, M, 3): rows [start, stop) of every material."""
        m, count = len(self.paths), stop - start
        # Every file's rows are read contiguously, then one transpose moves whole 12-byte (3,)
        # records: reading straight into (rows, M, 3) scattered each file's rows 12 M bytes
        # apart, and numpy copies a strided float array value by value (a chunk of 16384 rows
        # of 151 materials: 100 ms CPU that way, ~40 ms this way).
        by_file = np.empty((m, count, 3), dtype=np.float32)
        for j, (path, (offset, _)) in enumerate(zip(self.paths, self.offsets)):
            with open(path, "rb") as handle:
                handle.seek(offset + start * 3 * 4)
                if handle.readinto(memoryview(by_file[j]).cast("B")) != by_file[j].nbytes:
                    raise DatasetError(f"{path}: expected rows {start} to {stop}, found the file shorter")
        out = np.empty((count, m, 3), dtype=np.float32)
        record = np.dtype((np.void, 12))
        out.view(record).reshape(count, m)[:] = by_file.view(record).reshape(m, count).T
        return out


def _npy_data_offset(path: Path) -> tuple[int, tuple]:
    """(byte offset of the data, shape) of a C-ordered float32 (n, 3) .npy file."""
    with open(path, "rb") as handle:
        major, _ = np.lib.format.read_magic(handle)
        read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read(handle)
        if fortran or dtype != np.float32 or len(shape) != 2 or shape[1] != 3:
            raise DatasetError(f"{path}: expected a C-ordered float32 (n, 3) table, found {dtype} {shape}")
        return handle.tell(), shape
