"""Reachability of every valid grid cell on a rig, with the reason the others cannot be measured.

A cell is reachable when some candidate pose (``planner.candidates``) is within limits and
measurable. Cached on disk, keyed by the rig's kinematics, alignment, camera model and the grid.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from goniofrost.core.cache import atomic_replace, cache_path, content_key
from goniofrost.core.grid import MerlGrid

from .candidates import best_reason, candidate_poses
from .kinematics import Reason
from .rig import Rig

# Cells per chunk: bounds the temporary arrays to a few tens of MB whatever the grid.
CHUNK_CELLS = 1 << 18
_CACHE_VERSION = "reach-v2"


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


def reachability(rig: Rig, grid: MerlGrid, *, steps=None, use_cache: bool = True, progress: bool = False) -> ReachMap:
    """Reachability of every valid cell of ``grid`` on ``rig`` (computed once, then read from disk;
    ``progress``: a bar on stderr while computing); ``steps``: the axes' command lattices (deg,
    ``candidate_poses``): what a plan scheduled with the same steps can measure."""
    path = _cache_file(rig, grid, steps)
    reason = _read_cached(path, grid.n_valid) if use_cache else None
    if reason is None:
        reason = compute_reasons(rig, grid, steps=steps, progress=progress)
        if use_cache:
            _write_cached(path, reason)
    reason.setflags(write=False)
    mask = reason == Reason.OK
    mask.setflags(write=False)
    return ReachMap(mask=mask, reason=reason, rig_hash=rig.kinematic_hash, grid=grid)


def compute_reasons(rig: Rig, grid: MerlGrid, *, steps=None, progress: bool = False) -> np.ndarray:
    """uint8 (n_valid,) Reason codes of the valid cells, computed in chunks (no cache).

    With a camera model the full grid takes a few seconds (four candidate poses per cell)."""
    from goniofrost.core.progress import progress_bar

    cells = grid.valid_cells
    reason = np.empty(cells.size, dtype=np.uint8)
    starts = range(0, cells.size, CHUNK_CELLS)
    for start in progress_bar(starts, asked=progress and len(starts) >= 2, desc="reachability", unit="chunk",
                              leave=False):
        part = cells[start:start + CHUNK_CELLS]
        _, _, reasons = candidate_poses(rig, *grid.cell_directions(part), steps=steps)
        reason[start:start + part.size] = best_reason(reasons)
    return reason


def rig_key(rig: Rig) -> list:
    """Everything of a rig that decides reachability: kinematics, alignment and camera model."""
    alignment = None if rig.alignment is None else rig.alignment.hash
    view = None if rig.view is None else rig.view.as_dict()
    return [rig.kinematic_hash, alignment, view]


def is_cached(rig: Rig, grid: MerlGrid, steps=None) -> bool:
    """Whether ``reachability(rig, grid, steps=steps)`` has a map on disk to read (without reading
    it: a stale entry it would compute again says True)."""
    return _cache_file(rig, grid, steps).is_file()


def _cache_file(rig: Rig, grid: MerlGrid, steps=None):
    lattice = [] if steps is None else [[float(v) for v in steps]]
    return cache_path("reach", content_key(_CACHE_VERSION, rig_key(rig), grid.as_dict(), *lattice), ".npy")


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
