"""Reachability of every valid grid cell on a rig, and why the others cannot be measured.

A cell is reachable when some inverse-kinematics branch puts every joint inside its limits.
Swapping light and camera (reciprocity) never changes reachability on a rig of DESIGN.md's kind:
the arm angle and the size of the tilt are symmetric in (w_i, w_o); so one inverse suffices.
Results are cached on disk (``goniofrost.core.cache``) keyed by the rig's kinematic hash and the grid.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from goniofrost.core.cache import atomic_replace, cache_path, content_key
from goniofrost.core.grid import MerlGrid

from .kinematics import Reason, inverse
from .rig import Rig

# Cells per chunk: bounds the temporary arrays to a few tens of MB whatever the grid.
CHUNK_CELLS = 1 << 18
_CACHE_VERSION = "reach-v1"


@dataclass(frozen=True)
class ReachMap:
    """Reachability of a grid's valid cells on one rig.

    ``mask``: bool (n_valid,), True where reachable. ``reason``: uint8 (n_valid,) ``Reason`` codes.
    """

    mask: np.ndarray
    reason: np.ndarray
    rig_hash: str
    grid: MerlGrid

    def counts(self) -> dict[str, int]:
        """Number of valid cells per reason name, e.g. ``{"OK": ..., "ARM_SEPARATION": ...}``."""
        tally = np.bincount(self.reason, minlength=len(Reason))
        return {r.name: int(tally[r]) for r in Reason}

    @property
    def fraction(self) -> float:
        """Fraction of the valid cells that are reachable."""
        return float(self.mask.mean()) if self.mask.size else 0.0


def reachability(rig: Rig, grid: MerlGrid, *, use_cache: bool = True) -> ReachMap:
    """Reachability of every valid cell of ``grid`` on ``rig`` (computed once, then read from disk)."""
    key = content_key(_CACHE_VERSION, rig.kinematic_hash, grid.as_dict())
    path = cache_path("reach", key, ".npy")
    reason = _read_cached(path, grid.n_valid) if use_cache else None
    if reason is None:
        reason = compute_reasons(rig, grid)
        if use_cache:
            _write_cached(path, reason)
    reason.setflags(write=False)
    mask = reason == Reason.OK
    mask.setflags(write=False)
    return ReachMap(mask=mask, reason=reason, rig_hash=rig.kinematic_hash, grid=grid)


def compute_reasons(rig: Rig, grid: MerlGrid) -> np.ndarray:
    """uint8 (n_valid,) Reason codes of the valid cells, computed in chunks (no cache)."""
    cells = grid.valid_cells
    reason = np.empty(cells.size, dtype=np.uint8)
    # The full grid takes about a second: no progress bar needed.
    for start in range(0, cells.size, CHUNK_CELLS):
        part = cells[start:start + CHUNK_CELLS]
        reason[start:start + part.size] = inverse(rig, *grid.cell_directions(part)).best_reason
    return reason


def _read_cached(path, n_valid: int) -> np.ndarray | None:
    try:
        reason = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        return None
    if reason.dtype != np.uint8 or reason.shape != (n_valid,):
        return None  # a stale or foreign entry: recompute
    return reason


def _write_cached(path, reason: np.ndarray) -> None:
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.save(fh, reason, allow_pickle=False)
    atomic_replace(tmp, path)
