"""Tabulate a dataset over blocks of grid cells on one thread per core.

numpy releases the GIL inside its kernels; BLAS is held to one thread meanwhile, since its own
threads cost more than they gain on these small products and would oversubscribe the cores.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

import numpy as np

from goniofrost.core.grid import MerlGrid

MAX_WORKERS = 8


def workers() -> int:
    """Threads to use: the cores this process may run on (at most MAX_WORKERS)."""
    return max(1, min(len(os.sched_getaffinity(0)), MAX_WORKERS))


def tabulate_blocks(evaluate_many: Callable, names: Sequence[str], grid: MerlGrid,
                    cells: np.ndarray, block_cells: int) -> np.ndarray:
    """float32 (len(names), cells.size, 3): ``evaluate_many(names, th, td, pd)`` per block of cells."""
    from threadpoolctl import threadpool_limits

    out = np.empty((len(names), cells.size, 3), dtype=np.float32)

    def block(start: int) -> None:
        part = cells[start:start + block_cells]
        out[:, start:start + part.size] = evaluate_many(names, *grid.flat_angles(part))

    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(workers()) as pool:
        list(pool.map(block, range(0, cells.size, block_cells)))  # list(): re-raise errors
    return out
