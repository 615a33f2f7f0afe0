"""Run the folds of a benchmark in local worker processes or on a Dask cluster.

Rows come back in fold order and do not depend on where folds run. Every fold runs with one BLAS
thread (more threads change the last digits): a Dask cluster must set OPENBLAS_NUM_THREADS=1.
"""
from __future__ import annotations

import os
import queue
import socket
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from goniofrost.bench.config import BenchConfig, BenchError
from goniofrost.bench.evaluate import designs_per_fold, run_fold


def run_folds(config: BenchConfig, path, names: list[str], jobs: int = 1,
              dask_address: str | None = None, progress: bool = True,
              done: dict | None = None, on_fold=None) -> list[dict]:
    """Evaluate every fold; returns all rows, fold by fold.

    done: {fold: rows} already evaluated (a resumed run); those folds are not run again.
    on_fold: called as on_fold(fold, rows) as each fold finishes (e.g. to checkpoint it).
    jobs: local worker processes (at least one); ignored with ``dask_address``.
    dask_address: the scheduler of an existing dask.distributed cluster (``tcp://host:port``);
        its workers must see the same file system path for the cached tables.
    """
    from goniofrost.core.progress import progress_bar

    results = dict(done or {})
    todo = [f for f in range(config.folds) if f not in results]

    def finished(fold, rows):
        results[fold] = rows
        if on_fold is not None:
            on_fold(fold, rows)

    total = len(todo) * designs_per_fold(config)
    # the project's bar: drawn on a terminal only (carriage returns are noise in a log)
    with progress_bar(total=total, asked=progress, desc="bench", unit="design", smoothing=0.05) as bar:
        if todo and dask_address:
            _run_dask(config, str(path), names, todo, dask_address, bar, finished)
        elif todo:
            _run_local(config, str(path), names, todo, max(1, jobs), bar, finished)
    return [row for f in range(config.folds) for row in results[f]]


def _run_local(config, path, names, todo, jobs, bar, finished) -> None:
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # no fork after BLAS threads started
    with mp.Manager() as manager, _blas_threads(1):
        ticks = manager.Queue()
        with ProcessPoolExecutor(max_workers=min(jobs, len(todo)), mp_context=ctx) as pool:
            futures = {pool.submit(run_fold, config, path, names, f, ticks.put): f for f in todo}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                _drain(ticks, bar)
                for future in done:
                    finished(futures[future], future.result())  # a worker's error is raised here


def _drain(ticks, bar) -> None:
    while True:
        try:
            bar.update(ticks.get_nowait())
        except queue.Empty:
            return


class _blas_threads:
    """Set the BLAS thread count that spawned workers inherit."""

    KEYS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

    def __init__(self, n: int) -> None:
        self.n, self.saved = str(n), {}

    def __enter__(self):
        self.saved = {k: os.environ.get(k) for k in self.KEYS}
        os.environ.update({k: self.n for k in self.KEYS})
        return self

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


# A TCP connect to a scheduler that is up answers within this (refused at once when nothing
# listens); dask's Client instead retries a refused connect until its timeout (30 s by default).
PROBE_TIMEOUT_S = 2.0
# dask's handshake with a port that answered (Client's ``timeout``: the initial connection)
CONNECT_TIMEOUT_S = 10


def check_dask_address(address: str) -> None:
    """Raise BenchError now, naming ``address``, unless dask.distributed is installed and a TCP
    connect to the scheduler's host and port succeeds within PROBE_TIMEOUT_S (schemes without a
    host and port, such as ucx://, are left to dask). For the command line to call before the
    tabulation, and ``_run_dask`` before handing the address to dask."""
    try:
        from distributed.comm.addressing import get_address_host_port, parse_address
    except ImportError as exc:
        raise BenchError("--dask needs dask.distributed: pip install 'goniofrost[dask]'") from exc
    try:
        if parse_address(address)[0] not in ("tcp", "tls"):
            return
        host, port = get_address_host_port(address)
    except ValueError as exc:
        raise BenchError(f"--dask {address}: expected a scheduler address such as tcp://HOST:8786 ({exc})") from None
    try:
        socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S).close()
    except OSError as exc:
        timed_out = isinstance(exc, TimeoutError)
        reason = f"no answer within {PROBE_TIMEOUT_S:g} s" if timed_out else (exc.strerror or str(exc))
        raise BenchError(f"--dask {address}: cannot connect to a Dask scheduler there ({reason})") from None


def _run_dask(config, path, names, todo, address, bar, finished) -> None:
    check_dask_address(address)
    from distributed import Client, as_completed

    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise BenchError(f"--dask {address}: cannot connect to a Dask scheduler there ({exc})") from exc
    with client:
        futures = {client.submit(run_fold, config, path, names, f, pure=False): f for f in todo}
        for future in as_completed(list(futures)):
            finished(futures[future], future.result())
            bar.update(designs_per_fold(config))
