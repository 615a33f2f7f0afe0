"""Read and write MERL ``.binary`` BRDF files.

Layout, little-endian: three int32 resolutions (n_th, n_td, n_pd) = (90, 90, 180), then the R, G
and B blocks of n float64 each, in flat-index order. Stored value = BRDF / scale, scale =
(1/1500, 1.15/1500, 1.66/1500); invalid cells are stored as -1.

In memory a BRDF is a float64 array (n_cells, 3) in 1/sr (columns R, G, B). **Missing values are
NaN**: every negative stored value reads as NaN, and NaN is written back as -1.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from goniofrost.core.atomic_file import write_buffers_atomic
from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import FULL_GRID, MerlGrid

RGB_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HEADER_BYTES = 3 * 4
MISSING_STORED = -1.0


class MerlFileError(GoniofrostError, ValueError):
    """A file is not a MERL .binary of the expected layout."""


def expected_size(grid: MerlGrid = FULL_GRID) -> int:
    """Size in bytes of a MERL file on ``grid``."""
    return HEADER_BYTES + 3 * grid.size * 8


def read_merl(path, grid: MerlGrid | None = None) -> np.ndarray:
    """Read a MERL .binary into a float64 (n_cells, 3) BRDF in 1/sr; missing values are NaN.

    The grid is taken from the header; when ``grid`` is given the header must match it.
    Raises MerlFileError naming the file, what was found and what was expected.
    """
    return _in_memory(_read_stored(Path(path), grid)[0])


def read_merl_complete(path, grid: MerlGrid | None = None) -> tuple[np.ndarray, MerlGrid]:
    """``read_merl`` of a BRDF to render, export or compare: (brdf, grid), on the file's own grid
    (``grid`` given: the header must match it, as ``read_merl``'s).

    Every cell above the horizon must hold a value: MerlFileError naming the file, the number of
    cells and the first one's (i_th, i_td, i_pd) for stored NaN or inf (anywhere: goniofrost never
    writes them, missing is -1), and for missing values (negative) on valid cells, which
    goniofrost's reconstructions never write either (they are -1 only below the horizon). One
    policy for ``preview``, ``export`` and ``compare``: a hole would otherwise draw as black,
    export as 0, or drop out of an error, each passing for a measured value.
    """
    path = Path(path)
    stored, grid = _read_stored(path, grid)
    _refuse_cells(path, grid, ~np.isfinite(stored).all(axis=0), "cells holding NaN or inf",
                  "expected finite values (-1 marks a missing value)")
    _refuse_cells(path, grid, (stored < 0).any(axis=0) & grid.valid_mask, "valid cells without a value (negative "
                  "in the file)", "expected a BRDF value >= 0 at every cell above the horizon")
    return _in_memory(stored), grid


def _in_memory(stored: np.ndarray) -> np.ndarray:
    """The BRDF (n_cells, 3) in 1/sr of stored values (3, n_cells); negative -> NaN (missing)."""
    brdf = stored.T * RGB_SCALE
    brdf[stored.T < 0] = np.nan
    return brdf


def _refuse_cells(path: Path, grid: MerlGrid, bad: np.ndarray, what: str, expected: str) -> None:
    """MerlFileError if any of the (grid.size,) mask ``bad`` is set: the count and the first cell."""
    if bad.any():
        first = tuple(int(v) for v in grid.unravel(int(np.flatnonzero(bad)[0])))
        raise MerlFileError(f"{path}: {what}: {int(bad.sum())}, first at (i_th, i_td, i_pd) = {first}; {expected}")


def _read_stored(path: Path, grid: MerlGrid | None) -> tuple[np.ndarray, MerlGrid]:
    """(the stored values (3, grid.size) as in the file, the file's grid), header and size checked."""
    file_grid = _read_header(path)
    if grid is not None and file_grid != grid:
        raise MerlFileError(
            f"{path}: header gives resolutions {file_grid.shape}, expected {grid.shape}"
        )
    size, want = path.stat().st_size, expected_size(file_grid)
    if size != want:
        kind = "truncated" if size < want else "oversized"
        raise MerlFileError(
            f"{path}: {kind} MERL file: {size} bytes, expected {want} bytes for a "
            f"{file_grid.shape} grid (12-byte header + 3 x {file_grid.size} float64)"
        )
    return np.fromfile(path, dtype="<f8", offset=HEADER_BYTES).reshape(3, file_grid.size), file_grid


def _read_header(path: Path) -> MerlGrid:
    try:
        header = np.fromfile(path, dtype="<i4", count=3)
    except FileNotFoundError:
        raise MerlFileError(f"{path}: no such file") from None
    except OSError as exc:   # a directory, unreadable: say so instead of a traceback
        raise MerlFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if header.size < 3:
        raise MerlFileError(
            f"{path}: truncated MERL file: {path.stat().st_size} bytes, expected at least a "
            f"{HEADER_BYTES}-byte header of three int32 resolutions"
        )
    if np.any(header < 1) or np.any(header > 10_000):
        if header.tobytes().startswith(b"tensor_file"[:HEADER_BYTES]):  # what goniofrost export writes
            raise MerlFileError(f"{path}: an RGL tensor file (the .bsdf of goniofrost export, Mitsuba's "
                                f"'measured' BSDF), not a MERL .binary: give the brdf.binary it was exported from")
        raise MerlFileError(
            f"{path}: wrong MERL header {tuple(int(v) for v in header)}, expected three positive "
            f"int32 resolutions such as (90, 90, 180)"
        )
    return MerlGrid(*(int(v) for v in header))


def write_merl(path, brdf: np.ndarray, grid: MerlGrid = FULL_GRID) -> None:
    """Write a (n_cells, 3) BRDF in 1/sr as a MERL .binary; NaN is written as -1.

    Negative values are refused (clamp them first); inf is refused. The file is written to a
    temporary name beside ``path`` and renamed, so a failure never leaves a partial file.
    """
    brdf = np.asarray(brdf, dtype=np.float64)
    if brdf.shape != (grid.size, 3):
        raise MerlFileError(f"write_merl: BRDF must have shape {(grid.size, 3)}, got {brdf.shape}")
    finite = np.isfinite(brdf)
    if np.isinf(brdf).any():
        raise MerlFileError(f"write_merl: {int(np.isinf(brdf).sum())} infinite values; refusing to write {path}")
    if (brdf[finite] < 0).any():
        raise MerlFileError(f"write_merl: negative BRDF values; clamp them before writing {path}")
    # Channel blocks built in place (no transposed copies, no joined bytes: 35 MB at full size).
    stored = np.empty((3, grid.size), dtype="<f8")
    for c in range(3):
        np.divide(brdf[:, c], RGB_SCALE[c], out=stored[c])
        stored[c][~finite[:, c]] = MISSING_STORED
    header = np.array(grid.shape, dtype="<i4")
    write_buffers_atomic(path, [header.tobytes(), memoryview(stored).cast("B")])


def valid_to_full(values: np.ndarray, grid: MerlGrid = FULL_GRID) -> np.ndarray:
    """Scatter (n_valid, 3) values on the valid cells into a (n_cells, 3) array, NaN elsewhere."""
    full = np.full((grid.size, 3), np.nan)
    full[grid.valid_cells] = values
    return full
