"""Threads for the compiled passes and the chunked products: how many, and running them.

Each part runs on one of our own threads with BLAS held to one thread (OpenBLAS's threads split
tall-skinny products poorly). The thread count is a parameter of every function (``threads=None``:
the default), never a module global.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable


from threadpoolctl import threadpool_limits

# More threads than this never help a memory-bound pass.
MAX_THREADS = 8
# Pieces of a pass per thread. More than one lets the thread on a free core take more of a pass
# when another process holds the other core, but in paired m = 60 runs at load 5-8 four pieces
# cost 10-20 % more CPU than one (3.0-3.4 s against 2.6-2.8 s) and no wall time was gained: on a
# machine that is not shared, one half per thread is the cheapest.
PIECES_PER_THREAD = 1


def default_threads() -> int:
    """Threads to use: the cores this process may run on, at most MAX_THREADS."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(MAX_THREADS, cores))


def resolve_threads(threads: int | None) -> int:
    """``threads`` checked (a positive integer), or the default for None."""
    if threads is None:
        return default_threads()
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads: expected a positive integer, found {threads!r}")
    return threads


def ranges(n: int, parts: int) -> list[tuple[int, int]]:
    """Up to ``parts`` contiguous non-empty ranges [lo, hi) covering 0 .. n, in order."""
    edges = [n * i // parts for i in range(parts + 1)]
    return [(lo, hi) for lo, hi in zip(edges[:-1], edges[1:]) if hi > lo]


def pass_ranges(n: int, threads: int) -> list[tuple[int, int]]:
    """The pieces of a pass over 0 .. n shared by ``threads`` threads: PIECES_PER_THREAD each
    (one piece on one thread), so a thread whose core another process keeps busy takes fewer
    pieces and the others take more instead of waiting for it."""
    return ranges(n, 1 if threads <= 1 else threads * PIECES_PER_THREAD)


def run_ranges(kernel: Callable, n: int, threads: int | None, *args, pool: ThreadPoolExecutor | None = None) -> list:
    """``kernel(*args, lo, hi)`` on the contiguous ``pass_ranges`` of 0 .. n, taken by the
    threads as they come free; the results in range order (a kernel that releases the GIL runs
    in parallel). ``pool``: an executor with ``threads`` workers to reuse across passes (else
    one is made for this pass)."""
    threads = resolve_threads(threads)
    parts = pass_ranges(n, threads)
    if len(parts) <= 1:
        return [kernel(*args, lo, hi) for lo, hi in parts]
    if pool is None:
        with ThreadPoolExecutor(max_workers=threads) as own:
            return run_ranges(kernel, n, threads, *args, pool=own)
    futures = [pool.submit(kernel, *args, lo, hi) for lo, hi in parts]
    return [f.result() for f in futures]


def map_chunks(fn: Callable, n: int, chunk: int, threads: int | None = None) -> list:
    """``fn(start, stop)`` for the chunks [start, start + chunk) of 0 .. n on ``threads`` threads
    with BLAS on one thread; the results in chunk order, so a reduction over them is the same
    whatever the number of threads."""
    starts = range(0, n, chunk)
    with threadpool_limits(limits=1, user_api="blas"):
        workers = min(resolve_threads(threads), len(starts))
        if workers <= 1:
            return [fn(s, min(s + chunk, n)) for s in starts]
        with ThreadPoolExecutor(max_workers=workers) as pool:
            return list(pool.map(lambda s: fn(s, min(s + chunk, n)), starts))


def imap_chunks(fn: Callable, n: int, chunk: int, threads: int | None = None):
    """Like ``map_chunks`` but yields the results in chunk order as they are ready (a running
    reduction holds a few results at a time, not all of them). BLAS is not limited: ``fn`` is
    for element-wise work, and the caller's reduction between results may use BLAS's threads."""
    starts = range(0, n, chunk)
    workers = min(resolve_threads(threads), len(starts))
    if workers <= 1:
        for s in starts:
            yield fn(s, min(s + chunk, n))
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = []
        for s in starts:
            pending.append(pool.submit(fn, s, min(s + chunk, n)))
            if len(pending) > 2 * workers:  # bounded read-ahead
                yield pending.pop(0).result()
        for future in pending:
            yield future.result()
