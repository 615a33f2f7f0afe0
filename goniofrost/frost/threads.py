"""Threads for the compiled passes and the chunked products: how many, and running them.

The selection kernels and the row-chunked products of training read memory-bound data; each
part runs on one of our own threads with BLAS limited to one thread meanwhile. OpenBLAS's own
threads split the small dimension of a tall-skinny product poorly and spin while waiting: on a
loaded 2-core host an (n x 219)^T (n x 219) Gram product took 12 x the wall time on two BLAS
threads that it takes on one (benchmarks/frost_speed.py ``blas``).

The thread count is a parameter of every function that uses threads (``threads=None``: the
default below), never a module global, so a caller or a test sets it per call.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable


from threadpoolctl import threadpool_limits

# More threads than this never help a memory-bound pass.
MAX_THREADS = 8


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


def run_ranges(kernel: Callable, n: int, threads: int | None, *args) -> list:
    """``kernel(*args, lo, hi)`` on contiguous ranges of 0 .. n, one per thread; the results in
    range order (a kernel that releases the GIL runs in parallel)."""
    parts = ranges(n, resolve_threads(threads))
    if len(parts) <= 1:
        return [kernel(*args, lo, hi) for lo, hi in parts]
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
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
